"""Speed against error for any scene (``hybrid converge``): the scene run at a ladder of time
steps (each half the last) and, optionally, of mesh resolutions, on the batch engine; the error of
each run's quantities of interest estimated against the Richardson extrapolation of the finest
runs, with the observed order of convergence.

    from hybrid import converge
    rows = converge("cantilever", dt_levels=3, out="outputs/converge")

Richardson (ratio 2): with three successive levels Q1, Q2, Q3 the observed order is
p = log2(|Q1 - Q2| / |Q2 - Q3|) and the extrapolated answer Q* = Q3 + (Q3 - Q2) / (2^p - 1);
a run's error is its distance from Q* (RMS over the common frames for time series). With both
ladders, Q** = Q*_dt + Q*_mesh - Q_finest. Where the differences do not shrink steadily (contact
events, fracture: p below 0.5 or above 6, or successive orders disagreeing), no extrapolation is
trusted: the error is the difference from the finest run, and the table says so. A quantity
whose finest three runs agree to a hundredth of the tolerance (a body resting through the run)
has converged: the finest run is its reference.
"""
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import quantities as qty
from .study import execute, write_table
from .variants import SettingError, combinations, make_variants, setting_pairs

RICHARDSON, FINEST = "richardson", "finest-difference"
# the most a time-step ladder's observed order can be and be trusted: the integrators are of
# order 1 (backward Euler, the rigid contact step) or 2 (Newmark). Three runs of the default
# scene's chaotic pile-up read orders 3.4 and 5.0 and recommended a step at 0.3% error that a
# fourth level showed 36% off
DT_ORDER_MOST = 2.5
# a quantity whose finest three runs agree to this share of the tolerance (times its scale) has
# converged as far as the recommendation can tell: its error cannot decide it
SETTLED = 0.01


@dataclass(frozen=True)
class Estimate:
    """The extrapolation of one ladder. reference: the best estimate of the exact values
    (frames, components). orders: observed order of each successive triple (coarse first).
    method: ``richardson`` or ``finest-difference`` (no trusted order)."""
    reference: np.ndarray
    orders: tuple
    method: str


def observed_orders(levels, ratio=2.0):
    """Observed order of each successive triple of ``levels`` (arrays, coarse to fine); None
    where a difference is zero."""
    d = [qty.distance(a, b) for a, b in zip(levels, levels[1:])]
    return tuple(math.log(a / b, ratio) if a > 0 and b > 0 else None for a, b in zip(d, d[1:])), d


def richardson(levels, ratio=2.0, highest=6.0, settled=0.0):
    """Extrapolate ``levels`` (arrays of one shape, coarse to fine, each step refined by
    ``ratio``) from the finest three. The order is trusted when every difference shrinks, the
    finest three approach the limit from one side (the coarsest of them is as far from the finest
    as the two differences add up to, within 20%: runs that swing about the limit can shrink their
    differences too), the finest order is between 0.5 and ``highest`` (what the ladder's methods
    can give, with a margin) and, with four or more levels, the last two orders agree within 0.6;
    otherwise the reference is the finest level (method ``finest-difference``). Runs that agree to 1e-9 of the largest value have converged (to
    1e-12, a cantilever's tip agreeing to 3e-12 read as an erratic order), as have the finest
    three where they differ by no more than ``settled`` (a distance: a body resting on the
    ground, its runs 28 nm apart in the contact solver's noise, read as erratic, left the finest
    runs without an error and the cheapest run under the tolerance unrecommended)."""
    finest = levels[-1]
    if len(levels) < 3:
        return Estimate(finest, (), FINEST)
    orders, d = observed_orders(levels, ratio)
    round_off = 1e-9 * max(float(np.max(np.abs(np.asarray(level, float)))) for level in levels)
    if d[-1] <= round_off and d[-2] <= round_off:
        return Estimate(finest, orders, RICHARDSON)       # converged exactly
    p = orders[-1]
    one_sided = qty.distance(levels[-3], finest) >= 0.8 * (d[-2] + d[-1])
    steady = one_sided and all(a > b for a, b in zip(d, d[1:]))
    agree = len(orders) < 2 or (orders[-2] is not None and abs(orders[-2] - p) <= 0.6)
    if p is None or not (0.5 <= p <= highest) or not steady or not agree:
        # no order to trust; runs settled far below what is asked have converged all the same
        settle = max(d[-2], d[-1], qty.distance(levels[-3], finest)) <= settled
        return Estimate(finest, orders, RICHARDSON if settle else FINEST)
    return Estimate(finest + (finest - levels[-2]) / (ratio ** p - 1.0), orders, RICHARDSON)


@dataclass(frozen=True)
class Rung:
    """One run of a ladder: ``group`` (the across settings, a tuple), time-step level ``i`` and
    mesh level ``j`` (0 the coarsest), and its settings."""
    group: tuple
    i: int
    j: int
    settings: dict


def ladder(scene, dt_levels, refine_levels=0, meshes=None, across=()):
    """The runs of a convergence study of ``scene`` (a parsed Scene): ``dt_levels`` time steps
    halving from the scene's, times ``refine_levels`` mesh levels (each FEM body's shape
    ``resolution`` halved per level, or ``meshes``: ``{body: [mesh files, coarse to fine]}``),
    for each combination of the ``across`` settings (``[(key, values)]``). Frames are written
    every whole number of the coarsest time steps (``output_fps`` rounded to that), so that every
    run has them at the same times. A list of Rung."""
    if dt_levels < 1 or refine_levels < 0:
        raise SettingError("--dt needs at least 1 level and --refine at least 0")
    if dt_levels < 2 and refine_levels < 2:
        raise SettingError(f"--dt {dt_levels}: a ladder needs at least 2 levels (3 for an observed "
                           f"order), of time steps (--dt) or of meshes (--refine)")
    refined = _mesh_settings(scene, refine_levels, meshes or {})
    laddered = {"simulation.dt", "simulation.output_fps"} | set(refined)
    for key, _ in across:
        if key in laddered:
            what = "time step" if key.startswith("simulation.") else "mesh"
            raise SettingError(f"--set {key}: the {what} ladder sets it in every run; set it "
                               f"in the scene file (the ladder starts from the scene's)")
    dt = scene.simulation.dt
    # frames every whole number of the coarsest steps, so every run writes them at the same times
    fps = 1.0 / (dt * max(1, round(1.0 / (scene.simulation.output_fps * dt))))
    rungs = []
    for extra in combinations(list(across)):
        group = tuple(extra.items())
        for j in range(max(refine_levels, 1)):
            for i in range(dt_levels):
                settings = dict(extra) | {"simulation.dt": dt / 2 ** i, "simulation.output_fps": fps}
                settings |= {key: values[j] for key, values in refined.items()}
                rungs.append(Rung(group, i, j, settings))
    return rungs


def _mesh_settings(scene, levels, meshes):
    """``{key: [value per mesh level]}``: a mesh ladder for each listed body, halved resolutions
    for the other FEM bodies meshed from a shape; a box meshed by default has each of its default
    cells split 2, 4, ... times instead (``shape.refine``: its default cells may be longer along
    its long sides, and its default element order is kept)."""
    from .deformable import default_resolution
    if levels < 2:
        if meshes:
            raise SettingError(f"--mesh {next(iter(meshes))}: needs --refine N, N the number of "
                               f"meshes in the ladder (at least 2)")
        return {}
    out = {}
    bodies = {b.name: b for b in scene.bodies}
    for name, files in meshes.items():
        if name not in bodies:
            raise SettingError(f"--mesh {name}: no body '{name}'; bodies: {', '.join(bodies)}")
        if len(files) != levels:
            raise SettingError(f"--mesh {name}: lists {len(files)} meshes; --refine {levels} needs {levels}")
        missing = [f for f in files if not Path(f).is_file()]
        if missing:     # (else each level's run told it, under --set settings nobody gave)
            raise SettingError(f"--mesh {name}: no such file: {', '.join(missing)}")
        out[f"bodies.{name}.mesh"] = [str(Path(f).resolve()) for f in files]
    for b in scene.bodies:
        if b.model != "rigid" and b.shape is not None and b.name not in meshes:
            if b.shape.type == "box" and b.shape.resolution is None:
                out[f"bodies.{b.name}.shape.refine"] = [b.shape.refine * 2 ** j for j in range(levels)]
                continue
            h = b.shape.resolution or default_resolution(b.shape)
            out[f"bodies.{b.name}.shape.resolution"] = [h / 2 ** j for j in range(levels)]
    if not out:
        raise SettingError("--refine: no FEM or auto body is meshed from a shape; list a mesh "
                           "ladder with --mesh BODY=coarse.msh,fine.msh,...")
    return out


def estimate_group(runs, names, ratio=2.0, tol=0.0):
    """Errors of one group's runs (``[(rung, RunQuantities or None)]``; None: the run failed) for
    each quantity in ``names``. Returns ``{name: (errors by rung, local orders by rung, method,
    scale)}``. A quantity whose finest runs agree to within :data:`SETTLED` of ``tol`` (the
    recommendation's relative error) is taken as converged (:func:`richardson`)."""
    ok = {(r.i, r.j): q for r, q in runs if q is not None}
    I = max(r.i for r, _ in runs)
    J = max(r.j for r, _ in runs)
    out = {}
    for name in names:
        values = {key: q.get(name) for key, q in ok.items()}
        times = qty.common_times(list(values.values())) if values else None
        at = {key: qty.resampled(v, times) for key, v in values.items()}
        dt_axis = [at[(i, J)] for i in range(I + 1) if (i, J) in at]
        mesh_axis = [at[(I, j)] for j in range(J + 1) if (I, j) in at]
        complete = len(dt_axis) == I + 1 and len(mesh_axis) == J + 1
        # an axis of one level needs no estimate; one of two cannot give an order
        size = _scale(name, at.get((I, J)), ok) or 0.0
        est = [richardson(axis, ratio, highest, SETTLED * tol * size)
               for axis, highest in ((dt_axis, DT_ORDER_MOST), (mesh_axis, 6.0))
               if len(axis) > 1] if complete else []
        reference, method = at.get((I, J)), FINEST
        if est and all(e.method == RICHARDSON for e in est):
            reference, method = sum(e.reference for e in est) - (len(est) - 1) * at[(I, J)], RICHARDSON
        errors, orders = {}, {}
        for r, q in runs:
            # no error for a failed run, nor for the finest one when it is the reference itself
            if q is None or reference is None or (method == FINEST and (r.i, r.j) == (I, J)):
                continue
            errors[r.i, r.j] = qty.distance(at[(r.i, r.j)], reference)
            column = [at[(i, r.j)] for i in range(r.i, min(r.i + 3, I + 1)) if (i, r.j) in at]
            orders[r.i, r.j] = observed_orders(column, ratio)[0][0] if len(column) == 3 else None
        out[name] = (errors, orders, method, _scale(name, reference, ok))
    return out


def _scale(name, reference, ok):
    """The scale of quantity ``name`` (quantities.scale) in a group whose runs are ``ok``: a
    position's at the end by how far the finest run moved it over the whole run (its end value
    alone says where the body is, not how far it went)."""
    if reference is None:
        return None
    if name.endswith("@end") and qty.positional(name) and ok:
        return qty.scale(name, ok[max(ok)].get(name.removesuffix("@end")).values)
    return qty.scale(name, reference)


def row_groups(rows):
    """The rows of each group of a study (one per combination of the settings it was run
    across with ``--set``): ``[(label, rows)]``, the label ``""`` for a study of one group, else
    ``"key=value, ..."``."""
    columns = list(rows[0]) if rows else []
    keys = columns[1:columns.index("dt")] if "dt" in columns else []
    groups = {}
    for row in rows:
        groups.setdefault(tuple(row[k] for k in keys), []).append(row)
    return [(", ".join(f"{k}={v}" for k, v in zip(keys, values)), members)
            for values, members in groups.items()]


def pareto(points):
    """Indices of the (cost, error) points no other point beats in both (ties kept)."""
    best = []
    for k, (c, e) in enumerate(points):
        if not any((c2 <= c and e2 <= e) and (c2 < c or e2 < e) for c2, e2 in points):
            best.append(k)
    return best


def converge(scene, out, dt_levels=3, refine_levels=0, meshes=None, across=(), quantities=None,
             tol=0.01, workers=None, scheduler=None, progress=False, plot=True):
    """Run ``scene`` (a file or built-in name) at ``dt_levels`` halving time steps (and
    ``refine_levels`` mesh levels, see :func:`ladder`; ``across``: ``["KEY=V1,V2"]`` or
    ``{key: values}`` settings each with a ladder of its own) on Dask, estimate each run's error in ``quantities`` (names of
    :mod:`hybrid.app.quantities`; default :func:`hybrid.app.quantities.defaults`), write
    ``out/convergence.csv`` (and ``out/convergence.png`` with ``plot``) and return its rows (a
    list of dicts). ``tol``: the relative error the recommendation asks for; the rows' ``pareto``
    and ``recommended`` columns mark the Pareto-best runs and the cheapest run whose every
    quantity's error is below ``tol`` times its scale."""
    from ..simulation import scene_path
    from .scene import load_scene
    path = scene_path(scene)
    base = load_scene(path)
    names = check_quantities(base, quantities)
    if not 0.0 < tol < 1.0:
        raise SettingError(f"tol={tol}: give a relative error between 0 and 1")
    rungs = ladder(base, dt_levels, refine_levels, meshes, setting_pairs(across))
    variants = make_variants(path, [r.settings for r in rungs])
    out = Path(out)
    records = execute(variants, out, workers, scheduler, progress)
    out.mkdir(parents=True, exist_ok=True)
    rows = _rows(base, rungs, records, names, tol, refine_levels)
    write_table(rows, out / "convergence.csv")
    if plot:
        from .plots import plot_convergence
        plot_convergence(rows, names, tol, out / "convergence.png")
    return rows


def check_quantities(scene, names):
    """The quantity names to use: ``names`` checked against the scene (SettingError naming an
    unknown one and listing some that exist), or the defaults."""
    if not names:
        return qty.defaults(scene)
    known = qty.available(scene)
    for name in names:
        if name.removesuffix("@end") not in known:
            raise SettingError(f"--quantity {name}: no such quantity in this scene (plastic_strain "
                               f"needs a yield_stress, cracks a breakable body); for example: "
                               + ", ".join(qty.defaults(scene)))
    return list(names)


def _rows(scene, rungs, records, names, tol, refine_levels):
    """The ``convergence.csv`` rows of the finished runs."""
    groups = {}
    for rung, record in zip(rungs, records):
        q = qty.RunQuantities(record["folder"], scene) if record["status"] == "ok" else None
        groups.setdefault(rung.group, []).append((rung, q))
    estimates = {g: estimate_group(runs, names, tol=tol) for g, runs in groups.items()}
    rows = []
    for rung, record in zip(rungs, records):
        summary_time = float(rung.settings.get("simulation.duration", scene.simulation.duration))
        row = {"id": record["id"], **dict(rung.group), "dt": rung.settings["simulation.dt"],
               "resolution": _resolution(rung, scene) if refine_levels > 1 else "",
               "status": record["status"], "error": record["error"] or "", "wall_s": record["wall_s"],
               "wall_per_sim_s": record["wall_s"] / summary_time if record["wall_s"] else ""}
        worst = 0.0
        for name in names:
            errors, orders, method, size = estimates[rung.group][name]
            error, order = errors.get((rung.i, rung.j)), orders.get((rung.i, rung.j))
            row[f"error:{name}"] = "" if error is None else error
            row[f"order:{name}"] = "" if order is None else order
            row[f"estimate:{name}"] = method
            relative = None if error is None else (error / size if size else (0.0 if error == 0 else math.inf))
            row[f"relative:{name}"] = "" if relative is None else relative
            worst = None if relative is None or worst is None else max(worst, relative)
        row["max_relative_error"] = "" if worst is None else worst
        row["folder"] = record["folder"]
        rows.append(row)
    _mark(rows, tol)
    return rows


def _resolution(rung, scene):
    """The rung's first refined body's resolution (m; a box refined from its default mesh: the
    shortest side of its cells) or mesh file."""
    from .deformable import default_box_mesh
    for key, value in rung.settings.items():
        if key.endswith(".shape.resolution") or key.endswith(".mesh"):
            return value
        if key.endswith(".shape.refine"):
            body = next(b for b in scene.bodies if f"bodies.{b.name}.shape.refine" == key)
            return default_box_mesh(body.shape.size, body.order).resolution / value
    return ""


def _mark(rows, tol):
    """``pareto`` and ``recommended`` columns over the runs with an error estimate."""
    scored = [k for k, r in enumerate(rows) if r["max_relative_error"] != "" and r["wall_per_sim_s"] != ""]
    front = {scored[k] for k in pareto([(rows[i]["wall_per_sim_s"], rows[i]["max_relative_error"])
                                        for i in scored])}
    under = [i for i in scored if rows[i]["max_relative_error"] <= tol]
    pick = min(under, key=lambda i: rows[i]["wall_per_sim_s"]) if under else None
    for k, row in enumerate(rows):
        row["pareto"] = k in front
        row["recommended"] = k == pick
