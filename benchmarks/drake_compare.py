"""Side by side with Drake's deformable FEM: the same tet mesh, material, damping and dt.

Cases (P1 tets, gravity 9.81 m/s^2 down):

- ``cube_ground``: a soft cube (0.2 m, 6 x 6 x 6 cells = 1,296 tets, E = 100 kPa, nu = 0.3,
  1000 kg/m^3, stiffness damping 0.01 s) dropped from 5 cm onto the ground (friction 0.5),
  0.5 s at dt = 1 ms; ours floating frame, Drake linear corotated.
- ``cube_box``: the same with a 1 kg rigid box (0.1 m) resting on it.
- ``cantilever_960_linear`` / ``_corotated``: a beam 1 m x 0.2 m x 0.2 m (10 x 4 x 4 cells =
  960 tets, E = 100 MPa, nu = 0.3, 1000 kg/m^3, mass damping 100 1/s, stiffness damping 1 ms)
  clamped at x = 0 and sagging under its own weight, 0.3 s at dt = 1 ms (settled); ours
  anchored linear (an anchored body has no floating frame) against Drake linear, ours
  corotated against Drake linear corotated.
- ``cantilever_7680_*``: the same beam at 20 x 8 x 8 cells (7,680 tets).

The mesh is made here (fem.mesh.box_tet_mesh), written once as .vtu for our scene and once as
legacy .vtk for Drake, in world coordinates. Ours runs in this process through
``hybrid.Simulation`` (a warm-up run first: numba kernels loaded, as Drake's are compiled);
Drake runs in its own interpreter (Python >= 3.12) through benchmarks/drake_driver.py. Each side
samples the nodes every 10 steps (lowest z for the ground penetration) and is timed from the
first step to the last, the model built outside the timing; the runs of the two alternate.
Reported per case: wall time and process CPU time per simulated second, ours / Drake (medians
of ``--repeats`` runs; the CPU ratio is the steadier one on a loaded machine); for the
cantilevers the tip deflection (mean z displacement of the tip face nodes) of both and their
difference; for the cubes the settled height of the top face, the box's height and the deepest
ground penetration over the run (positive: below z = 0).

Drake's interpreter: ``--drake-python PATH``, else ``$DRAKE_PYTHON`` (only that one), else the
first of ``python3.13`` / ``python3.12`` on PATH and ``~/drake-venv/bin/python`` that imports
pydrake. Without one the benchmark says so on one line (``SKIP drake_compare: ...``) and exits 0. Setting it up: benchmarks/README.md.

    OPENBLAS_NUM_THREADS=1 python benchmarks/drake_compare.py [--repeats 3] [--cases cube_ground ...]
"""
import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import meshio
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import write_csv  # noqa: E402

from fem.mesh import box_tet_mesh  # noqa: E402
from hybrid import Simulation  # noqa: E402

DRIVER = Path(__file__).resolve().parent / "drake_driver.py"
SAMPLE_EVERY = 10


@dataclass
class Case:
    """One comparison: mesh, material and what each side runs."""
    name: str
    size: tuple
    cells: tuple
    offset: tuple             # m, added to the centred mesh: world coordinates
    young: float
    density: float
    duration: float
    ours_frame: str           # "floating" or "corotated"
    drake_material: str       # "linear", "linear_corotated" or "corotated"
    mass_damping: float = 0.0
    stiffness_damping: float = 0.0
    poisson: float = 0.3
    dt: float = 1e-3
    ground: float | None = None        # friction of the ground (z = 0), or no ground
    box: dict | None = None            # a rigid box resting on the body
    clamp: bool = False                # held at its x-minimum face
    previous: str = ""                 # the ratio measured before (issue 24)
    tets: int = field(init=False, default=0)


def cases():
    cube = dict(size=(0.2, 0.2, 0.2), cells=(6, 6, 6), offset=(0.0, 0.0, 0.15), young=1e5,
                density=1000.0, duration=0.5, ours_frame="floating",
                drake_material="linear_corotated", stiffness_damping=0.01, ground=0.5)
    box = {"size": [0.1, 0.1, 0.1], "mass": 1.0, "position": [0.0, 0.0, 0.3 + 1e-3], "friction": 0.5}
    beam = dict(size=(1.0, 0.2, 0.2), offset=(0.5, 0.0, 0.0), young=1e8, density=1000.0,
                duration=0.3, mass_damping=100.0, stiffness_damping=1e-3, clamp=True)
    out = [Case("cube_ground", previous="0.16-0.21", **cube),
           Case("cube_box", box=box, previous="0.16-0.21", **cube)]
    for cells, label, before in (((10, 4, 4), "960", ("0.33", "0.83")),
                                 ((20, 8, 8), "7680", ("0.035", "0.28"))):
        out.append(Case(f"cantilever_{label}_linear", cells=cells, ours_frame="floating",
                        drake_material="linear", previous=before[0], **beam))
        out.append(Case(f"cantilever_{label}_corotated", cells=cells, ours_frame="corotated",
                        drake_material="linear_corotated", previous=before[1], **beam))
    return out


def mesh_of(case):
    """The case's tet mesh in world coordinates: ``(points (n, 3), tets (t, 4))``."""
    points, tets = box_tet_mesh(list(case.size), case.cells)
    case.tets = len(tets)
    return points + np.asarray(case.offset), tets


def scene_text(case):
    """Our scene file of the case (the mesh file ``body.vtu`` beside it, in world coordinates)."""
    lines = ['[simulation]', f'name = "{case.name}"', f'duration = {case.duration!r}', f'dt = {case.dt!r}',
             'output_fps = 100', '']
    if case.ground is not None:
        lines += ['[[planes]]', f'friction = {case.ground!r}', '']
    lines += ['[[bodies]]', 'name = "body"', 'model = "fem"', 'mesh = "body.vtu"',
              f'density = {case.density!r}', f'young = {case.young!r}', f'poisson = {case.poisson!r}',
              f'frame = "{case.ours_frame}"', f'friction = {case.ground if case.ground is not None else 0.5!r}',
              f'damping = {{ mass = {case.mass_damping!r}, stiffness = {case.stiffness_damping!r} }}']
    if case.clamp:
        x0 = case.offset[0] - 0.5 * case.size[0]
        lines += ['', '[[bodies.anchors]]', f'box = [[{x0 - 1e-6!r}, -1.0, -1.0], [{x0 + 1e-6!r}, 1.0, 1.0]]']
    if case.box is not None:
        b = case.box
        density = b["mass"] / float(np.prod(b["size"]))
        lines += ['', '[[bodies]]', 'name = "box"', f'shape = {{ type = "box", size = {b["size"]} }}',
                  f'density = {density!r}', f'position = {b["position"]}', f'friction = {b["friction"]!r}']
    return "\n".join(lines) + "\n"


def run_ours(scene_file, case):
    """One run of ours: ``(wall s, cpu s, final node positions, lowest z, box z or None)``."""
    sim = Simulation.from_toml(scene_file)
    steps = int(round(case.duration / case.dt))
    lowest = float(sim.state.fem[0].x[:, 2].min())
    wall0, cpu0 = time.perf_counter(), time.process_time()
    for k in range(1, steps + 1):
        sim.step()
        if k % SAMPLE_EVERY == 0 or k == steps:
            lowest = min(lowest, float(sim.state.fem[0].x[:, 2].min()))
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    box_z = float(sim.body("box").position[2]) if case.box is not None else None
    return wall, cpu, sim.state.fem[0].x.copy(), lowest, box_z, sim


def run_drake(python, vtk_path, case, repeats, work):
    """Drake's runs of the case (drake_driver.py in its interpreter): its result dict."""
    spec = {"mesh": str(vtk_path), "material": case.drake_material, "young": case.young,
            "poisson": case.poisson, "density": case.density, "mass_damping": case.mass_damping,
            "stiffness_damping": case.stiffness_damping, "dt": case.dt, "duration": case.duration,
            "sample_every": SAMPLE_EVERY, "ground": case.ground, "box": case.box,
            "clamp_x": (case.offset[0] - 0.5 * case.size[0] + 1e-6) if case.clamp else None,
            "repeats": repeats}
    case_file, result_file = work / f"{case.name}_case.json", work / f"{case.name}_drake.json"
    case_file.write_text(json.dumps(spec))
    done = subprocess.run([python, str(DRIVER), str(case_file), str(result_file)],
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{case.name}: Drake's driver failed:\n{done.stderr[-2000:]}")
    return json.loads(result_file.read_text())


def imports_pydrake(python):
    """Whether ``python`` runs and imports pydrake's multibody plant."""
    try:
        return subprocess.run([python, "-c", "import pydrake.multibody.plant"], capture_output=True,
                              timeout=120).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def find_drake_python(explicit):
    """``(interpreter or None, where it was looked for)``: the one named by ``explicit`` or
    $DRAKE_PYTHON if given (only that one), else the first of python3.13, python3.12 and
    ~/drake-venv/bin/python that imports pydrake."""
    named = explicit or os.environ.get("DRAKE_PYTHON")
    if named:
        return (named if imports_pydrake(named) else None), f"{named} does not import pydrake"
    candidates = [shutil.which("python3.13"), shutil.which("python3.12"),
                  str(Path.home() / "drake-venv" / "bin" / "python")]
    for python in filter(None, candidates):
        if imports_pydrake(python):
            return python, ""
    return None, "no Python with Drake found (give --drake-python or DRAKE_PYTHON)"


def tip_deflection(points, reference, case):
    """Mean z displacement (m) of the nodes on the beam's free end face."""
    tip = reference[:, 0] > reference[:, 0].max() - 1e-9
    return float((points[tip, 2] - reference[tip, 2]).mean())


def top_height(points, reference):
    """Mean z (m) of the nodes that started on the top face."""
    top = reference[:, 2] > reference[:, 2].max() - 1e-9
    return float(points[top, 2].mean())


def main(argv=None):
    all_cases = cases()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--drake-python", help="a Python that imports pydrake (Drake >= 1.58)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs of each side (medians)")
    parser.add_argument("--cases", nargs="+", choices=[c.name for c in all_cases],
                        default=[c.name for c in all_cases])
    parser.add_argument("--csv", default="outputs/bench/drake_compare.csv")
    args = parser.parse_args(argv)

    python, why = find_drake_python(args.drake_python)
    if python is None:
        print(f"SKIP drake_compare: {why}; setup in benchmarks/README.md")
        return 0
    work = Path(tempfile.mkdtemp(prefix="drake_compare_"))
    rows, goals = [], []
    try:
        for case in (c for c in all_cases if c.name in args.cases):
            points, tets = mesh_of(case)
            folder = work / case.name
            folder.mkdir()
            meshio.write(folder / "body.vtu", meshio.Mesh(points, [("tetra", tets)]))
            meshio.write(folder / "body.vtk", meshio.Mesh(points, [("tetra", tets)]), binary=True)
            scene_file = folder / "scene.toml"
            scene_file.write_text(scene_text(case))

            run_ours(scene_file, case)                         # warm-up: kernels loaded
            ours, drakes = [], []
            for _ in range(args.repeats):                      # interleaved: the same load on both
                ours.append(run_ours(scene_file, case))
                drakes.append(run_drake(python, folder / "body.vtk", case, 1, work))
            drake = drakes[-1] | {"walls": [d["walls"][0] for d in drakes],
                                  "cpus": [d["cpus"][0] for d in drakes]}
            reference = np.asarray(drake["reference"])
            sim = ours[-1][5]
            if not np.allclose(reference, points, atol=1e-12):
                raise RuntimeError(f"{case.name}: Drake holds the vertices in another order")
            final_ours, final_drake = ours[-1][2], np.asarray(drake["final"])
            if final_ours.shape != final_drake.shape:
                raise RuntimeError(f"{case.name}: {len(final_ours)} nodes here, {len(final_drake)} in Drake")

            wall_ours = statistics.median(r[0] for r in ours) / case.duration
            cpu_ours = statistics.median(r[1] for r in ours) / case.duration
            wall_drake = statistics.median(drake["walls"]) / case.duration
            cpu_drake = statistics.median(drake["cpus"]) / case.duration
            ratio = wall_ours / wall_drake
            row = {"case": case.name, "tets": case.tets, "nodes": len(points), "dt": case.dt,
                   "simulated_s": case.duration, "repeats": args.repeats,
                   "ours_frame": case.ours_frame, "drake_material": case.drake_material,
                   "ours_wall_per_sim_s": wall_ours, "drake_wall_per_sim_s": wall_drake,
                   "wall_ratio": ratio, "ours_cpu_per_sim_s": cpu_ours,
                   "drake_cpu_per_sim_s": cpu_drake, "cpu_ratio": cpu_ours / cpu_drake,
                   "previous_wall_ratio": case.previous, "drake_version": drake["drake_version"]}
            if case.clamp:
                tip_ours = tip_deflection(final_ours, points, case)
                tip_drake = tip_deflection(final_drake, points, case)
                row |= {"tip_deflection_ours_m": tip_ours, "tip_deflection_drake_m": tip_drake,
                        "tip_deflection_difference_m": tip_ours - tip_drake}
            if case.ground is not None:
                row |= {"penetration_ours_m": max(0.0, -min(r[3] for r in ours)),
                        "penetration_drake_m": max(0.0, -drake["min_z"]),
                        "top_height_ours_m": top_height(final_ours, points),
                        "top_height_drake_m": top_height(final_drake, points)}
            if case.box is not None:
                row |= {"box_z_ours_m": ours[-1][4], "box_z_drake_m": drake["box_z"]}
            rows.append(row)
            print_case(row, sim)
            goals.append((case.name, ratio))
        columns = list(dict.fromkeys(k for row in rows for k in row))
        write_csv(args.csv, [{k: row.get(k, "") for k in columns} for row in rows])
        print(f"\nwrote {args.csv} (Drake {rows[0]['drake_version']} in {python}; machine shared with "
              f"other jobs: the CPU ratios are the steadier figure)")
        for name, ratio in goals:
            print(f"GOAL drake_{name}: measured={ratio:.3f} target=1.0 {'met' if ratio <= 1.0 else 'not met'}")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


def print_case(row, sim):
    print(f"\n{row['case']}: {row['tets']} tets, {row['nodes']} nodes, dt = {row['dt']:g} s, "
          f"{row['simulated_s']:g} s simulated, ours {row['ours_frame']} / Drake {row['drake_material']}, "
          f"medians of {row['repeats']}")
    print(f"  wall per simulated s: ours {row['ours_wall_per_sim_s']:.3f} s, Drake "
          f"{row['drake_wall_per_sim_s']:.3f} s, ours/Drake {row['wall_ratio']:.3f} "
          f"(before: {row['previous_wall_ratio']})")
    print(f"  CPU per simulated s:  ours {row['ours_cpu_per_sim_s']:.3f} s, Drake "
          f"{row['drake_cpu_per_sim_s']:.3f} s, ours/Drake {row['cpu_ratio']:.3f}")
    if "tip_deflection_ours_m" in row:
        print(f"  tip deflection: ours {row['tip_deflection_ours_m']:.6e} m, Drake "
              f"{row['tip_deflection_drake_m']:.6e} m, difference {row['tip_deflection_difference_m']:.2e} m")
    if "penetration_ours_m" in row:
        print(f"  deepest ground penetration: ours {row['penetration_ours_m']:.2e} m, Drake "
              f"{row['penetration_drake_m']:.2e} m; top face settled at ours {row['top_height_ours_m']:.5f} m, "
              f"Drake {row['top_height_drake_m']:.5f} m")
    if "box_z_ours_m" in row:
        print(f"  box centre height: ours {row['box_z_ours_m']:.5f} m, Drake {row['box_z_drake_m']:.5f} m")


if __name__ == "__main__":
    sys.exit(main())
