"""Rigid pile: N boxes of 0.1 m dropped in a loose grid into a walled bin, ours against pybullet.

The bin is a ground plane and four wall planes. Every box is 1 kg (density 1000), friction 0.5,
restitution 0; dt = 1/240 s. Both engines step the identical scene in this process, one after the
other, ``--repeats`` times (ours built afresh each time); pybullet keeps its default solver settings
(its friction combines by product, so each of its objects gets sqrt(0.5) to make every contact 0.5
as in ours, where it combines by geometric mean). Then a few hundred more of our steps run under
cProfile to show where the time goes.

    OPENBLAS_NUM_THREADS=1 python benchmarks/rigid_pile.py [--n 100 1000] [--seconds 2] [--repeats 3]

Prints steps/s per engine (medians over the repeats; wall clock, and process CPU time, which a
loaded machine disturbs less), the median of the repeats' ratios ours/pybullet, the pile's mean
height and escaped boxes for both, the profile, and per N one line
``GOAL rigid_pile_<N>_vs_pybullet: measured=<ratio> target=1.0 met|not met`` (the wall-clock
ratio); writes outputs/bench/rigid_pile.csv.
"""
import argparse
import cProfile
import io
import math
import os
import pstats
import time
import tomllib
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from hybrid import Simulation
from hybrid.app.scene import parse_scene

from _common import write_csv

BOX = 0.1                  # m, edge
SPACING = 0.15             # m, grid pitch of the initial drop
DT = 1.0 / 240.0
FRICTION = 0.5
CSV_PATH = Path("outputs/bench/rigid_pile.csv")


def pile_layout(n, seed=0):
    """Initial box centres (n, 3) m, small yaw angles (n,) rad, and the bin's inner half-width m."""
    side = int(math.ceil(n ** (1.0 / 3.0)))
    rng = np.random.default_rng(seed)
    idx = np.arange(n)
    i, j, k = idx % side, (idx // side) % side, idx // (side * side)
    centre = (np.stack([i, j, np.zeros(n)], axis=1) - [(side - 1) / 2, (side - 1) / 2, 0]) * SPACING
    centre[:, 2] = BOX + k * SPACING
    centre[:, :2] += rng.uniform(-0.01, 0.01, (n, 2))
    yaw = rng.uniform(-0.3, 0.3, n)
    return centre, yaw, side * SPACING / 2 + 0.05


def wall_planes(half):
    """(point, normal) of the ground and the four walls (normals point into the bin)."""
    return [((0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
            ((-half, 0.0, 0.0), (1.0, 0.0, 0.0)), ((half, 0.0, 0.0), (-1.0, 0.0, 0.0)),
            ((0.0, -half, 0.0), (0.0, 1.0, 0.0)), ((0.0, half, 0.0), (0.0, -1.0, 0.0))]


def scene_toml(n, seconds):
    centre, yaw, half = pile_layout(n)
    vec = lambda v: "[" + ", ".join(repr(float(x)) for x in v) + "]"
    parts = [f"[simulation]\nname = \"rigid_pile_{n}\"\nduration = {seconds!r}\ndt = {DT!r}\n"]
    for point, normal in wall_planes(half):
        parts.append(f"[[planes]]\npoint = {vec(point)}\nnormal = {vec(normal)}\n"
                     f"friction = {FRICTION}\nrestitution = 0.0\n")
    for b, (c, a) in enumerate(zip(centre, yaw)):
        parts.append(f"[[bodies]]\nname = \"box{b}\"\nshape = {{ type = \"box\", size = {vec([BOX] * 3)} }}\n"
                     f"density = 1000.0\nposition = {vec(c)}\norientation = {vec([math.cos(a / 2), 0, 0, math.sin(a / 2)])}\n"
                     f"friction = {FRICTION}\nrestitution = 0.0\n")
    return "\n".join(parts)


def pile_stats(z, xy, half):
    """Mean centre height (m), boxes escaped from the bin, deepest centre below resting height (m)."""
    escaped = int(np.sum((np.abs(xy) > half + 1e-3).any(axis=1) | (z < 0)))
    return float(np.mean(z)), escaped, float(max(0.0, BOX / 2 - np.min(z)))


def run_ours(n, seconds, profile_steps):
    scene = parse_scene(tomllib.loads(scene_toml(n, seconds)), f"<rigid pile {n}>", Path("."))
    t0 = time.perf_counter()
    sim = Simulation(scene)
    build_time = time.perf_counter() - t0
    steps = int(round(seconds / DT))
    sim.step()                                 # first step outside the timing (JIT cache load)
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps - 1):
        sim.step()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rs = sim.state.rigid
    stats = pile_stats(rs.position[:, 2], rs.position[:, :2], pile_layout(n)[2])
    profile_text = ""
    if profile_steps > 0:
        profiler = cProfile.Profile()
        profiler.enable()
        for _ in range(profile_steps):
            sim.step()
        profiler.disable()
        buffer = io.StringIO()
        pstats.Stats(profiler, stream=buffer).sort_stats("tottime").print_stats(8)
        profile_text = buffer.getvalue()
    return {"engine": "ours", "build_seconds": build_time, "steps": steps - 1, "wall_seconds": wall,
            "cpu_seconds": cpu, "stats": stats, "profile": profile_text}


def run_pybullet(n, seconds):
    import pybullet as p
    centre, yaw, half = pile_layout(n)
    client = p.connect(p.DIRECT)
    try:
        p.setGravity(0, 0, -9.81, physicsClientId=client)
        p.setTimeStep(DT, physicsClientId=client)
        mu = math.sqrt(FRICTION)               # pybullet multiplies the two sides' coefficients
        for point, normal in wall_planes(half):
            shape = p.createCollisionShape(p.GEOM_PLANE, planeNormal=normal, physicsClientId=client)
            body = p.createMultiBody(0, shape, basePosition=point, physicsClientId=client)
            p.changeDynamics(body, -1, lateralFriction=mu, restitution=0.0, physicsClientId=client)
        box_shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[BOX / 2] * 3, physicsClientId=client)
        bodies = []
        for c, a in zip(centre, yaw):
            body = p.createMultiBody(1.0, box_shape, basePosition=c.tolist(),
                                     baseOrientation=[0, 0, math.sin(a / 2), math.cos(a / 2)],
                                     physicsClientId=client)
            p.changeDynamics(body, -1, lateralFriction=mu, restitution=0.0, physicsClientId=client)
            bodies.append(body)
        steps = int(round(seconds / DT))
        p.stepSimulation(physicsClientId=client)
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(steps - 1):
            p.stepSimulation(physicsClientId=client)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        pos = np.array([p.getBasePositionAndOrientation(b, physicsClientId=client)[0] for b in bodies])
    finally:
        p.disconnect(client)
    return {"engine": "pybullet", "steps": steps - 1, "wall_seconds": wall, "cpu_seconds": cpu,
            "stats": pile_stats(pos[:, 2], pos[:, :2], half)}


def median_runs(runs):
    """One engine's repeats as one result: median wall and CPU time, the last run's pile."""
    out = dict(runs[-1])
    for key in ("wall_seconds", "cpu_seconds"):
        out[key] = float(np.median([r[key] for r in runs]))
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, nargs="+", default=[100, 1000], help="box counts")
    parser.add_argument("--seconds", type=float, default=2.0, help="simulated time per run (s)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="runs of each engine per box count (medians are reported)")
    parser.add_argument("--profile-steps", type=int, default=200,
                        help="extra steps of ours run under cProfile after the last repeat (0: none)")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    try:
        import pybullet  # noqa: F401
        have_pybullet = True
    except ImportError:
        have_pybullet = False
        print("pybullet not importable (pip install pybullet, or the project's bench extra): "
              "timing ours only")
    rows, goals = [], []
    for n in args.n:
        runs = {"ours": [], "pybullet": []}
        for r in range(args.repeats):      # the engines alternate, so both see the same load
            last = r == args.repeats - 1
            runs["ours"].append(run_ours(n, args.seconds, args.profile_steps if last else 0))
            if have_pybullet:
                runs["pybullet"].append(run_pybullet(n, args.seconds))
        results = [median_runs(v) for v in runs.values() if v]
        rates = {r["engine"]: r["steps"] / r["wall_seconds"] for r in results}
        cpu_rates = {r["engine"]: r["steps"] / r["cpu_seconds"] for r in results}
        ratio = cpu_ratio = float("nan")
        if have_pybullet:   # median over the repeats of each repeat's ratio
            ratio = float(np.median([p["wall_seconds"] / o["wall_seconds"]
                                     for o, p in zip(runs["ours"], runs["pybullet"])]))
            cpu_ratio = float(np.median([p["cpu_seconds"] / o["cpu_seconds"]
                                         for o, p in zip(runs["ours"], runs["pybullet"])]))
        print(f"\n== {n} boxes, {args.seconds:g} s at dt = 1/240 s, medians of {args.repeats} runs "
              f"(ours built in {results[0]['build_seconds']:.2f} s)")
        for r in results:
            mean_z, escaped, sunk = r["stats"]
            e = r["engine"]
            print(f"{e:>9}: {rates[e]:9.1f} steps/s wall, {cpu_rates[e]:9.1f} per CPU second  "
                  f"({r['steps']} steps in {r['wall_seconds']:.2f} s)  mean z {mean_z:.4f} m, "
                  f"escaped {escaped}, deepest sink {sunk * 1e3:.2f} mm")
            rows.append({"n": n, "engine": e, "seconds": args.seconds, "dt": DT,
                         "repeats": args.repeats, "steps": r["steps"],
                         "wall_seconds": r["wall_seconds"], "cpu_seconds": r["cpu_seconds"],
                         "steps_per_second": rates[e], "steps_per_cpu_second": cpu_rates[e],
                         "ratio_ours_over_pybullet": ratio if e == "ours" else "",
                         "cpu_ratio_ours_over_pybullet": cpu_ratio if e == "ours" else "",
                         "mean_height": mean_z, "escaped": escaped, "deepest_sink": sunk})
        if have_pybullet:
            print(f"ratio ours / pybullet: {ratio:.3f} wall, {cpu_ratio:.3f} CPU time")
            goals.append(f"GOAL rigid_pile_{n}_vs_pybullet: measured={ratio:.3g} target=1.0 "
                         f"{'met' if ratio >= 1.0 else 'not met'}")
        if results[0]["profile"]:
            print(f"where our time goes ({args.profile_steps} more steps, top 8 by tottime):")
            print(results[0]["profile"])
    write_csv(CSV_PATH, rows)
    print(f"wrote {CSV_PATH}")
    for line in goals:
        print(line)


if __name__ == "__main__":
    main()
