"""The convergence estimator (``hybrid converge``) against answers known exactly: Richardson on
sequences of known order, a deformable cube sliding down an incline with friction (x(t) in closed
form), a ball bouncing with restitution, and a cantilever's tip deflection against beam theory.
The estimated error must be within a factor of 3 of the true error at every level."""
import csv
import math
from pathlib import Path

import numpy as np
import pytest

from hybrid import converge
from hybrid.app.cli import main
from hybrid.app.converge import DT_ORDER_MOST, FINEST, RICHARDSON, pareto, richardson

G = 9.81


@pytest.fixture(scope="module")
def scheduler():
    """One local Dask cluster (two single-threaded workers) for this module's studies, reached
    through its address as a remote scheduler would be."""
    from dask.distributed import LocalCluster
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None, silence_logs=40) as cluster:
        yield cluster.scheduler_address


def _trajectory(folder, body):
    rows = [r for r in csv.DictReader(open(Path(folder) / "bodies.csv")) if r["body"] == body]
    return (np.array([float(r["time"]) for r in rows]),
            np.array([[float(r[c]) for c in "xyz"] for r in rows]))


def _rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


@pytest.mark.parametrize("order", [1.0, 2.0])
def test_richardson_recovers_the_limit_and_order_of_a_power_law(order):
    exact = np.array([[1.0, -2.0, 0.5]])
    levels = [exact + np.array([[0.3, 0.1, -0.2]]) * (0.1 / 2 ** k) ** order for k in range(4)]
    estimate = richardson(levels)
    assert estimate.method == RICHARDSON
    np.testing.assert_allclose(estimate.orders, [order, order], rtol=1e-9)
    np.testing.assert_allclose(estimate.reference, exact, atol=1e-12)


def test_richardson_falls_back_to_the_finest_level_when_differences_do_not_shrink():
    levels = [np.array([[v]]) for v in (1.0, 1.5, 1.1, 1.45)]
    estimate = richardson(levels)
    assert estimate.method == FINEST
    assert estimate.reference[0, 0] == 1.45


def test_richardson_distrusts_runs_that_swing_about_the_limit_and_trusts_round_off_agreement():
    """Differences that shrink while the runs swing from one side of the limit to the other
    (1.0, 1.53, 1.3, 1.51: |Q2 - Q3| < |Q1 - Q2|, yet the finest three are not one-sided) give no
    trusted order; runs equal to round-off have converged, with no erratic order to report."""
    swinging = [np.array([[v]]) for v in (1.0, 1.53, 1.3, 1.51)]
    assert richardson(swinging).method == FINEST
    same = [np.array([[1.0 + k * 1e-16, -2.0]]) for k in (0, 3, 1, 2)]
    estimate = richardson(same)
    assert estimate.method == RICHARDSON and np.array_equal(estimate.reference, same[-1])


def test_runs_settled_far_below_the_tolerance_are_converged_and_the_finest_gets_an_error():
    """A body resting on the ground through a ladder, its runs some tens of nanometres apart in
    the contact solver's noise (no steady order), left every finest run without an error, so that
    the cheapest run under the tolerance (a coarser mesh at a finer step) was never recommended.
    Runs that agree to a hundredth of the tolerance have converged; a real trend is still
    extrapolated, and noise as large as the tolerance is still no convergence."""
    resting = [np.array([[0.2, 0.0, 0.05 + e]]) for e in (0.0, 2.8e-8, 1.1e-8, 2.5e-8)]
    assert richardson(resting).method == FINEST
    settled = 0.01 * 0.01 * 0.02          # a hundredth of tol 0.01 of a 2 cm scale: 2 um
    estimate = richardson(resting, settled=settled)
    assert estimate.method == RICHARDSON and np.array_equal(estimate.reference, resting[-1])
    trend = [np.array([[1.0 + 1e-7 / 2 ** k]]) for k in range(4)]
    np.testing.assert_allclose(richardson(trend, settled=1e-6).reference, 1.0, rtol=0, atol=1e-13)
    noisy = [np.array([[0.05 + e]]) for e in (0.0, 2.8e-4, 1.1e-4, 2.5e-4)]
    assert richardson(noisy, settled=settled).method == FINEST


def test_pareto_keeps_the_runs_nothing_beats_in_both_cost_and_error():
    assert pareto([(1, 0.5), (2, 0.1), (3, 0.2), (4, 0.01), (1, 0.6)]) == [0, 1, 3]


def _incline(path, angle=30.0, mu=0.3):
    a = math.radians(angle)
    n = (-math.sin(a), 0.0, math.cos(a))
    path.write_text(f"""[simulation]
duration = 0.3
dt = 0.01
output_fps = 20

[[planes]]
normal = [{n[0]!r}, 0.0, {n[2]!r}]
friction = {mu!r}

[[bodies]]
name = "cube"
model = "fem"
young = 1e7
density = 1000.0
shape = {{ type = "box", size = [0.1, 0.1, 0.1] }}
position = [{0.05 * n[0]!r}, 0.0, {0.05 * n[2]!r}]
orientation = [{math.cos(a / 2)!r}, 0.0, {-math.sin(a / 2)!r}, 0.0]
friction = {mu!r}
""")
    down = np.array([-math.cos(a), 0.0, -math.sin(a)])
    return lambda t, x0: x0 + (0.5 * G * (math.sin(a) - mu * math.cos(a)) * t ** 2)[:, None] * down


def test_cube_sliding_down_an_incline_estimated_error_is_within_3x_of_the_closed_form(tmp_path, scheduler):
    """Backward Euler puts the deformable cube behind x(t) = g (sin a - mu cos a) t^2 / 2 by a
    first-order amount: the estimator finds order 1 and errors within a factor of 3."""
    exact = _incline(tmp_path / "incline.toml")
    rows = converge(tmp_path / "incline.toml", out=tmp_path / "out", dt_levels=4, scheduler=scheduler)
    assert [r["status"] for r in rows] == ["ok"] * 4
    assert {r["estimate:cube.com"] for r in rows} == {RICHARDSON}
    assert rows[0]["order:cube.com"] == pytest.approx(1.0, abs=0.2)
    for row in rows:
        t, x = _trajectory(row["folder"], "cube")
        true = _rms(x, exact(t, x[0]))
        assert true / 3 < row["error:cube.com"] < 3 * true, (row["dt"], row["error:cube.com"], true)
    assert (tmp_path / "out" / "convergence.png").stat().st_size > 1000


def test_bouncing_ball_estimate_agrees_with_the_exact_bounces_through_the_command_line(tmp_path, capsys,
                                                                                       scheduler):
    """The rigid ball's bounces (restitution 0.5) are exact to round-off at every time step; the
    estimate says so (errors below a nanometre: the runs agree to round-off)."""
    h, r, e = 0.5, 0.05, 0.5
    (tmp_path / "ball.toml").write_text(f"""[simulation]
duration = 0.8
dt = 0.004
output_fps = 100
[[planes]]
restitution = {e}
[[bodies]]
name = "ball"
shape = {{ type = "sphere", radius = {r} }}
position = [0.0, 0.0, {h + r}]
restitution = {e}
""")
    out = tmp_path / "out"
    assert main(["converge", str(tmp_path / "ball.toml"), "--dt", "3", "--scheduler", scheduler, "--out",
                 str(out), "--quiet", "--tol", "1e-6"]) == 0
    printed = capsys.readouterr().out
    # every dt is exact, so the cheapest by wall time is recommended: which one that is depends on
    # the machine's load (measured, not assumed)
    assert "recommended: dt = " in printed, printed
    rows = list(csv.DictReader(open(out / "convergence.csv")))
    assert {"dt", "resolution", "wall_s", "wall_per_sim_s", "error:ball.com", "order:ball.com"} <= set(rows[0])
    picked = [r for r in rows if r["recommended"] == "True"]
    assert len(picked) == 1 and f"recommended: dt = {float(picked[0]['dt']):.4g} s" in printed
    first_bounce = math.sqrt(2 * h / G)
    for row in rows:
        t, x = _trajectory(row["folder"], "ball")
        # after the first bounce the ball rises at e times its impact speed, and so on
        z = np.array([_bounce_height(tt, h, e, first_bounce) for tt in t]) + r
        assert _rms(x, np.column_stack([0 * z, 0 * z, z])) < 1e-9
        assert row["error:ball.com"] == "" or float(row["error:ball.com"]) < 1e-9


def test_wall_time_per_simulated_second_uses_each_runs_own_duration(tmp_path, scheduler):
    """``--set simulation.duration=...`` ran each group for its own time, and the rows divided
    every run's wall time by the scene file's duration (a 0.1 s run read four times cheaper than
    it was, and was recommended)."""
    (tmp_path / "ball.toml").write_text("""[simulation]
duration = 0.8
dt = 0.004
[[planes]]
[[bodies]]
name = "ball"
shape = { type = "sphere", radius = 0.05 }
position = [0.0, 0.0, 0.3]
""")
    rows = converge(tmp_path / "ball.toml", out=tmp_path / "out", dt_levels=2, scheduler=scheduler,
                    across=["simulation.duration=0.2,0.4"], plot=False)
    assert sorted({r["simulation.duration"] for r in rows}) == [0.2, 0.4]
    for row in rows:
        assert row["wall_per_sim_s"] == pytest.approx(row["wall_s"] / row["simulation.duration"])


def _bounce_height(t, h, e, t_fall):
    if t < t_fall:
        return h - 0.5 * G * t * t
    speed, start = G * t_fall * e, t_fall
    while t >= start + 2 * speed / G:
        start, speed = start + 2 * speed / G, speed * e
    s = t - start
    return max(speed * s - 0.5 * G * s * s, 0.0)


def test_cantilever_tip_deflection_estimated_error_is_within_3x_of_beam_theory(tmp_path, scheduler):
    """Quadratic tets at three halving resolutions: the estimate of each mesh's tip-deflection
    error (the settled deflection at the end) is within a factor of 3 of its distance from beam
    theory (Euler-Bernoulli with Timoshenko's shear term)."""
    length, side, young, nu, load = 1.0, 0.1, 2e11, 0.3, 1000.0
    area, inertia = side ** 2, side ** 4 / 12
    theory = load * length ** 3 / (3 * young * inertia) + load * length / (5 / 6 * young / (2 * (1 + nu)) * area)
    (tmp_path / "beam.toml").write_text(f"""[simulation]
duration = 0.2
dt = 0.01
gravity = [0.0, 0.0, 0.0]
output_fps = 10
[[bodies]]
name = "beam"
model = "fem"
shape = {{ type = "box", size = [{length}, {side}, {side}], resolution = 0.2 }}
position = [{length / 2}, 0.0, 0.0]
order = 2
young = {young}
poisson = {nu}
damping = {{ stiffness = 2e-4 }}
[[bodies.anchors]]
box = [[-0.501, -1, -1], [-0.499, 1, 1]]
[[bodies.loads]]
box = [[0.499, -1, -1], [0.501, 1, 1]]
force = [0.0, 0.0, {-load}]
""")
    name = "beam.load0.uz@end"
    rows = converge(tmp_path / "beam.toml", out=tmp_path / "out", dt_levels=1, refine_levels=3,
                    quantities=[name], scheduler=scheduler)
    assert [r["resolution"] for r in rows] == [0.2, 0.1, 0.05]
    assert {r[f"estimate:{name}"] for r in rows} == {RICHARDSON}
    for row in rows:
        tip = [float(r["uz"]) for r in csv.DictReader(open(Path(row["folder"]) / "regions.csv"))
               if r["region"] == "load0"][-1]
        true = abs(-tip - theory)
        assert true / 3 < row[f"error:{name}"] < 3 * true, (row["resolution"], row[f"error:{name}"], true)


def test_an_unknown_quantity_is_an_exit_2_error_naming_it(tmp_path, capsys):
    (tmp_path / "s.toml").write_text('[[bodies]]\nname = "box"\nshape = { type = "box", size = [0.1, 0.1, 0.1] }\n')
    code = main(["converge", str(tmp_path / "s.toml"), "--quantity", "box.spin", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "--quantity box.spin" in err and "box.com" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("name", ["box.plastic_strain", "cracks"])
def test_a_quantity_the_scene_cannot_give_is_an_exit_2_error(tmp_path, capsys, name):
    """No yield stress, nothing breakable: these were accepted and reported at 0, as erratic."""
    (tmp_path / "s.toml").write_text('[[bodies]]\nname = "box"\nmodel = "fem"\nyoung = 1e6\n'
                                     'shape = { type = "box", size = [0.1, 0.1, 0.1] }\n')
    code = main(["converge", str(tmp_path / "s.toml"), "--quantity", name, "--out", str(tmp_path / "o")])
    assert code == 2 and f"--quantity {name}: no such quantity in this scene" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_box_meshed_by_default_is_refined_by_splitting_its_default_cells(tmp_path):
    """``--refine`` on a plate with no ``resolution``: each rung splits the default mesh's cells
    (two quadratic layers through the thin side, longer cells along the long sides) 2, 4, ...
    times, keeping the order; halving a cubic ``resolution`` instead would have meshed the
    30 x 30 x 1 cm plate's first rung in linear tets 5 mm on a side (43,200 of them)."""
    import tomllib
    from hybrid.app.converge import ladder
    from hybrid.app.deformable import body_order, box_cells
    from hybrid.app.scene import parse_scene
    from hybrid.app.variants import apply_setting
    text = """
[simulation]
duration = 0.01
dt = 0.001
[[bodies]]
name = "plate"
model = "fem"
young = 7e10
density = 2700
shape = { type = "box", size = [0.3, 0.3, 0.01] }
"""
    base = tomllib.loads(text)
    rungs = ladder(parse_scene(base, "plate.toml", tmp_path), dt_levels=1, refine_levels=2)
    meshes = []
    for rung in rungs:
        data = tomllib.loads(text)
        for key, value in rung.settings.items():
            apply_setting(data, key, value)
        body = parse_scene(data, "plate.toml", tmp_path).bodies[0]
        meshes.append((body_order(body), box_cells(body.shape, body.order)))
    (order0, cells0), (order1, cells1) = meshes
    assert order0 == order1 == 2
    assert cells0[2] == 2                         # the default's two layers through the 1 cm side
    assert list(cells1) == [2 * c for c in cells0]   # every cell split in two along each side
    assert cells0[0] < 0.3 / 0.005                # longer cells along the long sides than across
    # the CSV's resolution column: the shortest cell side, halved
    from hybrid.app.converge import _resolution
    scene = parse_scene(base, "plate.toml", tmp_path)
    assert _resolution(rungs[1], scene) == pytest.approx(_resolution(rungs[0], scene) / 2)


def test_refine_must_be_a_whole_number_of_at_least_one(tmp_path):
    scene = tmp_path / "bad.toml"
    scene.write_text('[[bodies]]\nname = "b"\nshape = { type = "box", size = [1, 1, 1], refine = 0 }\n')
    code = main(["validate", str(scene)])
    assert code == 2


def test_a_mesh_ladder_needs_refine_and_replaces_a_shape(tmp_path, capsys):
    """--mesh without --refine ran one run on the shape and never looked at the files; with it,
    a body given by a shape failed ("needs exactly one of shape or mesh"): each rung's mesh
    takes the shape's place."""
    import shutil
    import tomllib
    from hybrid.app.converge import ladder
    from hybrid.app.scene import parse_scene
    from hybrid.app.variants import apply_setting
    root = Path(__file__).resolve().parents[1]
    for name in ("coarse.vtu", "fine.vtu"):
        shutil.copy(root / "meshes" / "cylinder_r5cm_h20cm.vtu", tmp_path / name)
    text = ('[simulation]\nduration = 0.01\ndt = 0.001\n[[bodies]]\nname = "can"\nmodel = "fem"\n'
            'young = 1e6\nshape = { type = "box", size = [0.1, 0.1, 0.1] }\n')
    (tmp_path / "s.toml").write_text(text)
    code = main(["converge", str(tmp_path / "s.toml"), "--mesh",
                 f"can={tmp_path / 'coarse.vtu'},{tmp_path / 'fine.vtu'}", "--out", str(tmp_path / "o")])
    assert code == 2 and "needs --refine N" in capsys.readouterr().err
    # a missing file is named once (each level's run told it, under --set settings never given)
    code = main(["converge", str(tmp_path / "s.toml"), "--refine", "2", "--mesh",
                 f"can={tmp_path / 'coarse.vtu'},{tmp_path / 'gone.vtu'}", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("gone.vtu") == 1 and "--set" not in err, err
    meshes = {"can": [str(tmp_path / "coarse.vtu"), str(tmp_path / "fine.vtu")]}
    rungs = ladder(parse_scene(tomllib.loads(text), "s.toml", tmp_path), 1, 2, meshes)
    for rung, mesh in zip(rungs, meshes["can"]):
        data = tomllib.loads(text)
        for key, value in rung.settings.items():
            apply_setting(data, key, value)
        body = parse_scene(data, "s.toml", tmp_path).bodies[0]
        assert body.shape is None and str(body.mesh) == mesh


def test_a_recommendation_measured_against_an_unconverged_finest_run_says_so():
    """With an erratic order the errors are differences from the finest run, which may itself be
    far from the answer (a ball rebounding from a plate: the recommended dt's true error was 0.18
    against the 0.098 it reported under --tol 0.15); the recommendation says so, and says
    nothing of the kind where Richardson's extrapolation stands."""
    from hybrid.app.study_cli import report

    def rows(method):
        return [{"id": f"00{k}", "dt": dt, "resolution": "", "status": "ok", "error:x": 0.1,
                 "estimate:x": method, "max_relative_error": e, "wall_per_sim_s": 1.0 + k,
                 "recommended": k == 1}
                for k, (dt, e) in enumerate([(1e-3, 0.3), (5e-4, 0.05), (2.5e-4, 0.0)])]

    erratic = report(rows("finest-difference"), 0.1)[-1]
    assert erratic.startswith("recommended: dt = 0.0005 s") and "not converged itself" in erratic
    assert "not converged" not in report(rows("richardson"), 0.1)[-1]


def test_three_levels_say_the_order_was_observed_once_when_any_quantity_is_extrapolated():
    """With three levels, an order extrapolated for one quantity and not for another printed no
    note that it was observed once (it was printed only when every quantity was extrapolated)."""
    from hybrid.app.study_cli import report

    def rows(methods):
        return [{"id": f"00{k}", "dt": dt, "resolution": "", "status": "ok",
                 **{f"error:{n}": 0.1 for n in methods}, **{f"estimate:{n}": m for n, m in methods.items()},
                 "max_relative_error": 0.1, "wall_per_sim_s": 1.0, "recommended": k == 2}
                for k, dt in enumerate([1e-3, 5e-4, 2.5e-4])]

    once = "each order was observed once"
    assert any(once in line for line in report(rows({"x": "richardson", "y": "finest-difference"}), 0.1))
    assert any(once in line for line in report(rows({"x": "richardson"}), 0.1))
    assert not any(once in line for line in report(rows({"y": "finest-difference"}), 0.1))


def test_a_time_step_order_no_integrator_gives_is_not_trusted():
    """Three runs whose differences shrink 10-fold (order 3.3) along a time-step ladder: the
    integrators are of order 1 or 2, so such an order is not asymptotic (the default scene's
    pile-up read 3.4 and 5.0, and its recommendation was 36% off); along a mesh ladder (P2
    elements converge faster) it is trusted."""
    levels = [np.array([[1.0 + 0.1 ** k]]) for k in range(3)]
    assert richardson(levels, highest=DT_ORDER_MOST).method == FINEST
    assert richardson(levels).method == RICHARDSON


def test_a_study_whose_runs_fail_exits_3_and_prints_their_messages(tmp_path, capsys, scheduler):
    """A batch script sees failed runs by the exit code (it was 0 even when every run failed),
    and the runs' messages are printed and kept in convergence.csv (only their status was)."""
    # a bar loaded at twice its plastic limit load (1 cm^2 at 100 MPa carries 10 kN) has no
    # equilibrium: it flows until the energy watch stops it
    (tmp_path / "s.toml").write_text("""[simulation]
duration = 0.3
dt = 0.001
gravity = [0.0, 0.0, 0.0]
[[bodies]]
name = "cube"
model = "fem"
shape = { type = "box", size = [0.1, 0.01, 0.01], resolution = 0.005 }
density = 2700.0
young = 70e9
yield_stress = 100e6
[[bodies.anchors]]
box = [[-1.0, -1.0, -1.0], [-0.049999, 1.0, 1.0]]
[[bodies.loads]]
box = [[0.049999, -1.0, -1.0], [1.0, 1.0, 1.0]]
force = [20000.0, 0.0, 0.0]
""")
    code = main(["converge", str(tmp_path / "s.toml"), "--dt", "2", "--scheduler", scheduler,
                 "--out", str(tmp_path / "o"), "--quiet"])
    assert code == 3
    printed = capsys.readouterr()
    assert printed.err.count("unstable: body 'cube'") == 2
    rows = list(csv.DictReader(open(tmp_path / "o" / "convergence.csv")))
    assert all(r["status"] == "unstable" and "body 'cube'" in r["error"] for r in rows)


def test_a_ladder_of_one_level_is_refused(tmp_path, capsys):
    """``--dt 1`` without a mesh ladder ran one run and printed a table with no estimate."""
    (tmp_path / "s.toml").write_text('[[bodies]]\nname = "b"\nshape = { type = "sphere", radius = 0.1 }\n')
    code = main(["converge", str(tmp_path / "s.toml"), "--dt", "1", "--out", str(tmp_path / "o")])
    assert code == 2 and "at least 2 levels" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_position_at_the_end_is_judged_against_how_far_the_body_moved():
    """``body.com@end`` was judged against the body's distance from the origin (its end value
    alone), so a scene placed away from the origin passed any ``--tol``: a body 100 m from the
    origin that falls 1 cm, its end position off by a first-order 1e-4 m per unit of dt, is
    judged against the centimetre it moved, as the whole series ``body.com`` is."""
    from types import SimpleNamespace
    from hybrid.app.converge import estimate_group
    from hybrid.app.quantities import Quantity

    class Run:
        def __init__(self, dt):
            t = np.linspace(0.0, 1.0, 11)
            z = 100.0 - 0.01 * t ** 2 - 1e-2 * dt * t        # off by a first-order error
            self.series = Quantity(t, np.column_stack([np.zeros_like(t), np.zeros_like(t), z]))

        def get(self, name):
            return Quantity(None, self.series.values[-1:]) if name.endswith("@end") else self.series

    runs = [(SimpleNamespace(i=i, j=0), Run(0.04 / 2 ** i)) for i in range(4)]
    out = estimate_group(runs, ["box.com@end", "box.com"])
    errors, _, method, scale = out["box.com@end"]
    assert method == RICHARDSON
    assert scale == pytest.approx(0.01, rel=1e-2)             # the travel, not 100 m
    assert errors[0, 0] / scale == pytest.approx(1e-2 * 0.04 / 0.01, rel=1e-2)
    assert out["box.com"][3] == pytest.approx(scale, rel=1e-2)


def test_a_quantity_of_a_body_whose_name_has_dots_is_read_from_that_body(tmp_path):
    """Bodies "ball" and "ball.v2": ``ball.v2.z`` was read as body "ball", column "v2.z", and the
    study ended "no such scene file or built-in scene (ball.v2.z)". The longest name counts."""
    from hybrid import Simulation
    from hybrid.app.quantities import RunQuantities
    scene = tmp_path / "two.toml"
    scene.write_text('[simulation]\nduration = 0.01\n[[bodies]]\nname = "ball"\n'
                     'shape = { type = "sphere", radius = 0.05 }\n[[bodies]]\nname = "ball.v2"\n'
                     'shape = { type = "sphere", radius = 0.05 }\nposition = [1, 0, 2]\n')
    sim = Simulation.from_toml(scene)
    sim.run(out=tmp_path / "run", progress=False, log=lambda m: None)
    z = RunQuantities(tmp_path / "run", sim.scene).get("ball.v2.z").values
    assert z[0, 0] == pytest.approx(2.0) and z[-1, 0] < 2.0


@pytest.mark.parametrize("command", ["sweep", "converge"])
def test_an_empty_out_is_refused_by_the_studies_as_by_run(command, capsys):
    args = ["--set", "simulation.dt=1e-4,5e-5"] if command == "sweep" else []
    assert main([command, "dent", *args, "--out", ""]) == 2
    assert "--out is empty" in capsys.readouterr().err


def test_a_mesh_ladder_of_two_levels_beside_a_time_ladder_of_three_is_the_reason_given():
    """--dt 3 --refine 2: every quantity fell back to differences, and the reason given was that
    they "do not shrink steadily", where the mesh ladder has two levels, which give no order."""
    from hybrid.app.study_cli import report
    rows = [{"id": f"{k}{j}", "dt": dt, "resolution": res, "status": "ok", "error:x": 0.1,
             "estimate:x": "finest-difference", "max_relative_error": 0.1, "wall_per_sim_s": 1.0,
             "recommended": False}
            for k, dt in enumerate([1e-3, 5e-4, 2.5e-4]) for j, res in enumerate([0.02, 0.01])]
    said = " ".join(report(rows, 0.1))
    assert "a ladder of 2 levels gives no observed order" in said and "shrink steadily" not in said
