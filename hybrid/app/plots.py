"""The studies' figures (matplotlib, off-screen): a sweep's figure against a swept value, and a
convergence study's error against cost."""
import re
from pathlib import Path

from .study import FIGURES as SWEEP_FIGURES
from .variants import SettingError


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _plot_parts(plot, keys, values):
    """``(figure, key)`` of ``plot``; without a key, the first of ``keys`` that takes more than one
    of its ``values`` (a list per key): a key set to one value is no axis."""
    figure, _, key = plot.partition(":")
    if not key and keys:
        varied = [k for k, v in zip(keys, values) if len({repr(x) for x in v}) > 1]
        key = (varied or keys)[0]
    return figure, key


def check_sweep_plot(plot, keys, values=None, bodies=None):
    """SettingError unless ``plot`` (``FIGURE`` or ``FIGURE:KEY``) names a figure of
    ``results.csv`` (or ``<body>.x|y|z``, a body of ``bodies`` if given) and one of the swept
    ``keys`` whose ``values`` (a list per key, if given) are numbers, which an axis can carry."""
    figure, key = _plot_parts(plot, keys, values or [[] for _ in keys])
    if figure not in SWEEP_FIGURES and not re.fullmatch(r".+\.[xyz]", figure):
        raise SettingError(f"--plot {plot}: give one of {', '.join(SWEEP_FIGURES)} or <body>.x|y|z, "
                           f"optionally :KEY")
    if figure not in SWEEP_FIGURES and bodies is not None and figure[:-2] not in bodies:
        raise SettingError(f"--plot {plot}: no body '{figure[:-2]}'; bodies: {', '.join(bodies)}")
    if key not in keys:
        raise SettingError(f"--plot {plot}: '{key}' is not a swept key; swept: {', '.join(keys) or 'none'}")
    if values is not None and not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                       for v in values[keys.index(key)]):
        raise SettingError(f"--plot {plot}: '{key}' takes values that are not numbers (vectors, "
                           f"words); plot against a swept key with number values")


def plot_sweep(rows, keys, plot, out):
    """``out/<figure>.png``: the figure of each ok run against the swept value (one line per
    combination of the other swept values). Returns the file's path."""
    plt = _pyplot()
    figure, key = _plot_parts(plot, keys, [[r[k] for r in rows] for k in keys])
    others = [k for k in keys if k != key]
    lines = {}
    for row in rows:
        if row["status"] == "ok" and row.get(figure, "") != "" and not isinstance(row[key], list):
            label = ", ".join(f"{k}={row[k]}" for k in others)
            lines.setdefault(label, []).append((row[key], float(row[figure])))
    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    for label, points in lines.items():
        points.sort()
        ax.plot(*zip(*points), "o-", label=label or None)
    ax.set_xlabel(key)
    ax.set_ylabel(figure)
    if any(lines):
        ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    path = Path(out) / f"{figure}.png"
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_convergence(rows, names, tol, path):
    """``path`` (a PNG): each quantity's error relative to its scale against wall time per
    simulated second, log-log, one line per quantity (and group of a ``--set``); the Pareto-best runs ringed, the
    recommended one starred, ``tol`` dashed."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=100)
    from .converge import row_groups
    scored = [r for r in rows if r["max_relative_error"] != ""]
    for group, members in row_groups(rows):        # a line per quantity and --set group
        for name in names:
            points = sorted((r["wall_per_sim_s"], _relative(r, name)) for r in members
                            if r in scored and r[f"error:{name}"] != "")
            points = [(c, e) for c, e in points if e is not None and e > 0]
            if points:
                ax.loglog(*zip(*points), "o-", ms=4, label=name + (f" [{group}]" if group else "")
                          + ("" if _trusted(members, name) else " (vs finest)"))
    front = [r for r in scored if r["pareto"] and r["max_relative_error"] > 0]
    if front:
        ax.loglog([r["wall_per_sim_s"] for r in front], [r["max_relative_error"] for r in front], "o",
                  ms=12, mfc="none", mec="black", label="Pareto-best (largest error)")
    picked = [r for r in scored if r["recommended"] and r["max_relative_error"] > 0]
    if picked:
        ax.loglog(picked[0]["wall_per_sim_s"], picked[0]["max_relative_error"], "*", ms=16,
                  color="gold", mec="black", label=f"recommended: dt = {picked[0]['dt']:.3g} s"
                  + (f", resolution = {picked[0]['resolution']}" if picked[0]["resolution"] != "" else "")
                  + "".join(f", {g}" for g, members in row_groups(rows) if g and picked[0] in members))
    ax.axhline(tol, ls="--", color="grey", lw=1, label=f"tol = {tol:g}")
    ax.set_xlabel("wall time per simulated second (s)")
    ax.set_ylabel("estimated error / quantity's scale")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def _trusted(rows, name):
    return all(r[f"estimate:{name}"] == "richardson" for r in rows)


def _relative(row, name):
    """A run's error in ``name`` relative to the quantity's scale, or None."""
    value = row.get(f"relative:{name}", "")
    return None if value == "" else value
