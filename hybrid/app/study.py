"""The batch engine: many variants of one scene run in parallel on Dask, each an ordinary run in
its own folder, and ``hybrid sweep``'s table of them.

    from hybrid import sweep
    rows = sweep("dent", {"bodies.plate.yield_stress": [2e8, 3e8]}, out="outputs/study")

A study folder holds ``runs/<id>/`` (the variant's scene file and the files ``hybrid run``
writes; ``hybrid run runs/<id>/<scene>.toml`` reruns one alone) and ``results.csv``. Runs go to a
local cluster of worker processes (one thread each, BLAS pinned to one thread) or to an existing
Dask scheduler; its workers must see the study folder at the same path (a shared file system).
A run whose ``summary.json`` says ``ok`` for the same scene file is kept and skipped when the
study runs again; an unstable or failed run is recorded and does not stop the others.
"""
import csv
import logging
import os
import signal
import sys
import threading
import time as clock
import traceback
from pathlib import Path

from . import run_lock
from .entry import Terminated
from .run_files import BODIES_CSV, read_summary
from .scene import SceneError
from .variants import SettingError, combinations, make_variants, setting_pairs

# one BLAS / OpenMP / numba thread per worker process: workers do not oversubscribe the cores
PINNED_THREADS = {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1,
                  "NUMBA_NUM_THREADS": 1}
FIGURES = ("wall_s", "steps_per_s", "simulated_time", "energy_drift", "linear_momentum_drift",
           "angular_momentum_drift", "plastic_dissipation", "cracks", "fragments")


def run_variant(scene_file, out_dir):
    """Run the scene file ``scene_file`` into ``out_dir`` as ``hybrid run`` does (a worker's task).
    Returns ``{"status": "ok" | "unstable" | "failed", "error": message or None, "wall_s"}``
    (``wall_s``: the run's stepping time, its summary's ``wall_time``, as for a run kept from
    before, so that runs compare alike; the whole task's time when it wrote no summary); never
    raises for a failed run."""
    from hybrid.coupling.stability import OutputFailure
    from hybrid.coupling.step import InstabilityError
    from ..simulation import Simulation
    start = clock.perf_counter()
    try:
        summary = _run_to_make(Simulation, scene_file, out_dir).run(out=out_dir, progress=False,
                                                                   log=lambda message: None)
        status, error = summary["status"], summary["error"]
        return {"status": status, "error": error, "wall_s": summary["wall_time"]}
    except InstabilityError as failure:     # (or its output could not be written: failed)
        status, error = "failed" if isinstance(failure, OutputFailure) else "unstable", str(failure)
    except Exception as failure:        # noqa: BLE001 (one run's failure must not end the study)
        status = "failed"
        error = f"{type(failure).__name__}: {failure}".strip()
        try:
            Path(out_dir, "error.txt").write_text(traceback.format_exc())
        except OSError:                 # the folder unseen from here: the error itself is what counts
            pass
    return {"status": status, "error": error, "wall_s": clock.perf_counter() - start}


def _run_to_make(Simulation, scene_file, out_dir):
    """The variant's run: continued from the checkpoint a stopped study left in ``out_dir`` (the
    run then ends in the files it would have written unstopped), else from the start; a
    checkpoint that cannot be continued (of an older scene text, or its folder damaged) is
    removed first (a run folder holding one is refused, ``Simulation.run``)."""
    from .checkpoint import CheckpointError
    saved = Path(out_dir, "checkpoint.npz")
    if saved.exists():
        try:
            return Simulation.resume(scene_file, out_dir)
        except CheckpointError:
            saved.unlink(missing_ok=True)
    return Simulation.from_toml(scene_file)


def finished(run_dir, scene_text, scene_name):
    """Whether ``run_dir`` holds a finished ``ok`` run of exactly the scene file ``scene_text``."""
    run_dir = Path(run_dir)
    scene_file = run_dir / scene_name
    try:
        summary = read_summary(run_dir)
        return (summary is not None and summary.get("status") == "ok"
                and scene_file.read_text() == scene_text)
    except (OSError, ValueError):
        return False


class StudyProgress:
    """One line on stderr: runs done, running and failed (quiet when disabled)."""

    def __init__(self, total, slots, enabled=True, stream=sys.stderr):
        self.total, self.slots, self.enabled, self.stream = total, max(1, slots), enabled, stream
        self.done = self.failed = self.skipped = 0
        self.tty = hasattr(stream, "isatty") and stream.isatty()

    def show(self, final=False):
        """Write the line (on a terminal over the last one)."""
        if not self.enabled:
            return
        running = 0 if final else min(self.slots, self.total - self.done - self.failed)
        text = (f"runs: {self.done + self.failed}/{self.total} done ({self.skipped} kept from "
                f"before), {running} running, {self.failed} failed")
        self.stream.write(("\r" + text + ("\n" if final else "")) if self.tty else text + "\n")
        self.stream.flush()


def _client(workers, scheduler):
    """A Dask client: to ``scheduler`` (an address) or to a new local cluster of ``workers``
    single-threaded worker processes (default: the number of cores). Returns (client, cluster)."""
    import dask
    from dask.distributed import Client, LocalCluster
    if scheduler:           # (its address checked by check_scheduler)
        return Client(scheduler, timeout="20s"), None
    n = int(workers or os.cpu_count() or 1)
    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {})
    # the workers start with Ctrl-C ignored (a terminal's goes to the whole process group): the
    # study stops them itself; given it too, they printed pages of tracebacks as they closed,
    # which their logs at CRITICAL leave out (a lost worker's run is a failed row anyway)
    ignored = signal.signal(signal.SIGINT, signal.SIG_IGN) if _main_thread() else None
    try:
        with dask.config.set({"distributed.nanny.pre-spawn-environ": environ | PINNED_THREADS}):
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=logging.CRITICAL)
    finally:
        if ignored is not None:
            signal.signal(signal.SIGINT, ignored)
    return Client(cluster), cluster


def _main_thread():
    """Whether this is the main thread (the only one that may set signal handlers)."""
    return threading.current_thread() is threading.main_thread()


def check_scheduler(address):
    """SettingError unless ``address`` reads as a Dask scheduler's (SCHEME://HOST:PORT, a scheme
    Dask knows, a port 1-65535): a wrong one waited 20 s to time out, or went unnoticed when every
    run was kept."""
    from distributed.comm import registry       # (distributed.comm registers its schemes there)
    from distributed.comm.addressing import parse_address, parse_host_port
    backends = registry.backends
    try:
        scheme, place = parse_address(str(address))
        port = parse_host_port(place)[1] if scheme != "inproc" else 1
    except (ValueError, TypeError) as err:
        raise SettingError(f"--scheduler {address}: not a scheduler address ({err}); give one as "
                           f"tcp://HOST:PORT") from None
    if scheme not in backends or not 0 < int(port) < 65536:
        raise SettingError(f"--scheduler {address}: not a scheduler address (scheme one of "
                           f"{', '.join(sorted(backends))}, port 1 to 65535); give one as tcp://HOST:PORT")


def execute(variants, out, workers=None, scheduler=None, progress=True):
    """Run ``variants`` (from :func:`hybrid.app.variants.make_variants`) under ``out/runs/``,
    skipping those finished before. Returns one record per variant, in order: ``id``, ``folder``,
    ``scene_file``, ``status``, ``error``, ``wall_s``, ``kept`` (finished before). ``workers``:
    None or a whole number of at least 1 (SettingError; -1 waited for workers for ever)."""
    if workers is not None and (isinstance(workers, bool) or not float(workers).is_integer()
                                or workers < 1):
        raise SettingError(f"workers={workers!r}: give a whole number of local processes, at least 1")
    if scheduler:       # (checked here: a study whose runs are all kept never reaches Dask)
        check_scheduler(scheduler)
    # one study at a time in a folder: a second one's runs failed on the first's run folders and
    # wrote there, and whichever ended last wrote the table (RunFolderBusy, nothing run)
    created = [p for p in (Path(out), *Path(out).parents) if not p.exists()]
    Path(out).mkdir(parents=True, exist_ok=True)
    try:
        run_lock.acquire(out)
        return _execute(variants, out, workers, scheduler, progress)
    finally:
        run_lock.release(out)
        for folder in created:          # (a scheduler that cannot be reached leaves nothing behind)
            try:
                folder.rmdir()
            except OSError:             # something was written there
                break


def _execute(variants, out, workers, scheduler, progress):
    """:func:`execute` with its arguments checked and the study folder's lock taken."""
    runs = Path(out) / "runs"
    records, todo, texts = [], [], []
    for v in variants:
        folder = runs / v.id
        scene_file = folder / v.file_name
        text = v.text()
        record = {"id": v.id, "folder": str(folder), "scene_file": str(scene_file), "kept": False}
        if finished(folder, text, v.file_name):
            summary = read_summary(folder)
            record.update(status="ok", error=None, wall_s=summary["wall_time"], kept=True)
        else:
            todo.append(record)
            texts.append(text)
        records.append(record)
    try:
        _dispatch(todo, texts, len(records), workers, scheduler, progress)
    except (KeyboardInterrupt, Terminated) as stop:
        said = "stopped (SIGTERM)" if isinstance(stop, Terminated) else "interrupted (Ctrl-C)"
        for record, text in zip(todo, texts):
            folder, name = Path(record["folder"]), Path(record["scene_file"]).name
            if "status" in record:
                continue
            if finished(folder, text, name):    # (it ended as the stop came, not yet collected)
                record.update(status="ok", error=None, wall_s=read_summary(folder)["wall_time"])
            else:
                record.update(status="interrupted", error=f"{said} before it finished", wall_s=None)
        raise StudyInterrupted(records, stop) from None
    return records


class StudyInterrupted(KeyboardInterrupt):
    """A study stopped by Ctrl-C or SIGTERM (``stop``, the exception that stopped it):
    ``records`` as :func:`execute` returns them, the runs it did not finish with status
    ``interrupted`` (their table is written before the stop goes on)."""

    def __init__(self, records, stop=None):
        super().__init__("interrupted")
        self.records, self.stop = records, stop


def _dispatch(todo, texts, total, workers, scheduler, progress):
    """Run the records' scene files (written from ``texts`` once Dask is reached: a scheduler
    that cannot be reached leaves nothing behind) on Dask, filling in status, error and wall
    time."""
    bar = StudyProgress(total, 1, enabled=progress)
    bar.done = bar.skipped = total - len(todo)
    if not todo:
        bar.show(final=True)
        return
    from dask.distributed import as_completed
    client, cluster = _client(workers, scheduler)
    try:
        for record, text in zip(todo, texts):
            folder = Path(record["folder"])
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "summary.json").unlink(missing_ok=True)
            Path(record["scene_file"]).write_text(text, encoding="utf-8")
        bar.slots = max(1, sum(client.nthreads().values()))
        # absolute paths: a scheduler's workers run from folders of their own (a relative study
        # folder failed every run there)
        futures = {client.submit(run_variant, str(Path(r["scene_file"]).resolve()),
                                 str(Path(r["folder"]).resolve()), pure=False,
                                 key=f"hybrid-run-{r['id']}-{os.urandom(4).hex()}"): r for r in todo}
        bar.show()
        for future in as_completed(futures):
            record = futures[future]
            try:
                record.update(future.result())
            except Exception as failure:    # noqa: BLE001 (a lost worker: recorded, not fatal)
                record.update(status="failed", error=f"{type(failure).__name__}: {failure}", wall_s=None)
            bar.failed += record["status"] != "ok"
            bar.done += record["status"] == "ok"
            bar.show()
        bar.show(final=True)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def final_positions(folder):
    """``{body: (x, y, z)}`` of each body's centre of mass at the last frame of a run folder."""
    path = Path(folder) / BODIES_CSV
    if not path.exists():
        return {}
    last = {}
    with open(path, newline="") as stream:
        for row in csv.DictReader(stream):
            last[row["body"]] = (float(row["x"]), float(row["y"]), float(row["z"]))
    return last


def result_row(record, settings):
    """A ``results.csv`` row: the swept values, status, error and the summary's figures."""
    row = dict(id=record["id"], **settings, status=record["status"], error=record["error"] or "")
    ended = record["status"] not in ("failed", "interrupted")   # (an interrupted run's files are partial)
    summary = read_summary(record["folder"]) if ended else None
    row.update({k: "" for k in FIGURES})
    row["wall_s"] = record.get("wall_s") or ""
    if summary:
        c, f = summary["conservation"], summary["fracture"]
        row.update(wall_s=summary["wall_time"], steps_per_s=summary["steps_per_second"],
                   simulated_time=summary["simulated_time"],
                   energy_drift=c["energy_relative_drift"],
                   linear_momentum_drift=c["linear_momentum_relative_drift"],
                   angular_momentum_drift=c["angular_momentum_relative_drift"],
                   plastic_dissipation=summary["plastic_dissipation"],
                   cracks=f["cracks"], fragments=f["fragments"])
    for body, xyz in (final_positions(record["folder"]) if ended else {}).items():
        row.update({f"{body}.{axis}": value for axis, value in zip("xyz", xyz)})
    row["folder"] = record["folder"]
    return row


def write_table(rows, path):
    """Write records (dicts; columns in first-seen order, missing cells empty) as CSV."""
    columns = list(dict.fromkeys(k for row in rows for k in row))
    with open(path, "w", newline="") as stream:
        writer = csv.DictWriter(stream, columns, restval="", lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _cell(v) for k, v in row.items()})


def _cell(value):
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, list):
        return ";".join(map(str, value))
    return value


def _in_python_words(error):
    """``error`` (SettingError or SceneError) about settings given as a dict from Python: in its
    keys' words, not the command line's --set and --zip."""
    def words(message):
        message = message.replace("--set key", "settings key").replace("--set ", "settings key ")
        return message.replace("--zip", "zipped=True")
    if isinstance(error, SceneError):
        return SceneError([words(p) for p in error.problems])
    return SettingError(words(str(error)))


def sweep(scene, settings, out, zipped=False, workers=None, scheduler=None, progress=False,
          plot=None):
    """Run every variant of ``scene`` (a scene file or built-in name) that ``settings`` makes
    (``{key: [values]}`` or ``["KEY=V1,V2", ...]``; the full grid, or with ``zipped`` the i-th
    values together) under ``out/runs/`` on Dask (``workers`` local processes, or the scheduler
    at address ``scheduler``), write ``out/results.csv`` and return its rows (a list of dicts).
    ``plot``: ``"FIGURE"`` or ``"FIGURE:KEY"`` draws ``out/FIGURE.png`` against the first key
    swept over more than one value (or that key). Raises SettingError or SceneError before anything runs for bad input."""
    from ..simulation import scene_path
    pairs = setting_pairs(settings)
    path = scene_path(scene)
    if plot:
        from .plots import check_sweep_plot
        from .scene import load_scene
        check_sweep_plot(plot, [k for k, _ in pairs], [v for _, v in pairs],
                         [b.name for b in load_scene(path).bodies])
    try:
        rows = combinations(pairs, zipped)
        variants = make_variants(path, rows)
    except (SettingError, SceneError) as error:
        if isinstance(settings, (list, tuple)):
            raise
        raise _in_python_words(error) from None
    out = Path(out)
    try:
        records, stopped = execute(variants, out, workers, scheduler, progress), None
    except StudyInterrupted as interrupted:
        records, stopped = interrupted.records, interrupted
    out.mkdir(parents=True, exist_ok=True)
    table = [result_row(r, v.settings) for r, v in zip(records, variants)]
    write_table(table, out / "results.csv")
    if stopped is not None:         # the runs that finished are in the table; a rerun keeps them
        raise stopped.stop if isinstance(stopped.stop, Terminated) else stopped
    if plot:
        from .plots import plot_sweep
        plot_sweep(table, [k for k, _ in pairs], plot, out)
    return table
