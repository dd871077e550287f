"""Fracture never ends a run in an exception: random small breakable scenes (panes, bars and
blocks; anchored edges or ends; rigid projectiles and fixed supports; speeds, strengths, element
orders, frames and fragment models) are stepped through the product's own loop
(``Simulation.run``). A run may end as unstable only through a genuine divergence that names the
body (InstabilityError), never through an unexpected error inside a step (StepFailure).

benchmarks/fracture_fuzz.py runs the same generator with more examples and bigger meshes.
Not drawn: a body whose every node is anchored (a coarse mesh inside its anchor boxes), whose
empty free system fem.solver cannot factorise yet (CHOLMOD fails and corrupts the heap).
"""
import tomllib
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hybrid import Simulation
from hybrid.app.scene import parse_scene
from hybrid.coupling.stability import InstabilityError, StepFailure

SHAPES = {                       # breakable body size (m) by kind
    "pane": (0.12, 0.12, 0.006),
    "bar": (0.16, 0.03, 0.03),
    "block": (0.06, 0.06, 0.06),
}
ANCHORS = ("none", "one_end", "two_ends", "all_edges")


@st.composite
def fracture_scenes(draw, finest=0.012, max_steps=8):
    """Parameters of a small breakable scene (a dict, see :func:`scene_toml`); ``finest`` (m) is
    the smallest mesh resolution drawn, ``max_steps`` the most steps a run takes."""
    kind = draw(st.sampled_from(sorted(SHAPES)))
    size = SHAPES[kind]
    return dict(
        kind=kind,
        # at most half the smaller side: a mesh with nodes at the ends and the edges only would be
        # anchored entirely (see the module docstring)
        resolution=min(draw(st.sampled_from([finest, 1.5 * finest, 2.5 * finest]))
                       * max(1.0, size[2] / 0.03), 0.5 * min(size[:2])),
        anchors=draw(st.sampled_from(ANCHORS)),
        order=draw(st.sampled_from([1, 1, 2])),
        frame=draw(st.sampled_from(["floating", "corotated"])),
        fragment_model=draw(st.sampled_from(["fem", "rigid", "auto"])),
        rigid_fragment_tets=draw(st.integers(1, 12)),
        fracture_stress=draw(st.sampled_from([1e5, 1e6, 1e7, 5e7])),
        young=draw(st.sampled_from([5e8, 7e10])),
        max_cracks=draw(st.sampled_from([4, 16, 64])),
        projectile=draw(st.sampled_from(["sphere", "box", "none"])),
        speed=draw(st.sampled_from([2.0, 10.0, 25.0, 60.0])),
        offset=draw(st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5))),
        support=draw(st.sampled_from(["none", "plane", "fixed_box", "both"])),
        gravity=draw(st.booleans()),
        dt=draw(st.sampled_from([1e-4, 5e-4, 1e-3])),
        steps=draw(st.integers(3, max_steps)),
    )


def _anchor_boxes(anchors, size):
    """Anchor boxes (body coordinates) of an anchoring choice: within 10% of the ends along x,
    or of every side."""
    hx, hy = 0.4 * size[0], 0.4 * size[1]
    low = f"[[-1, -1, -1], [{-hx}, 1, 1]]"
    high = f"[[{hx}, -1, -1], [1, 1, 1]]"
    boxes = {"none": [], "one_end": [low], "two_ends": [low, high],
             "all_edges": [low, high, f"[[-1, -1, -1], [1, {-hy}, 1]]", f"[[-1, {hy}, -1], [1, 1, 1]]"]}
    return "".join(f"[[bodies.anchors]]\nbox = {box}\n" for box in boxes[anchors])


def scene_toml(p):
    """The TOML text of the scene parameters ``p`` (:func:`fracture_scenes`)."""
    size = SHAPES[p["kind"]]
    top = size[2] / 2
    ox, oy = p["offset"][0] * size[0], p["offset"][1] * size[1]
    text = (f"[simulation]\nname = \"fuzz\"\ndt = {p['dt']}\nduration = {p['dt'] * p['steps']}\n"
            f"gravity = [0.0, 0.0, {-9.81 if p['gravity'] else 0.0}]\n")
    if p["support"] in ("plane", "both"):
        text += f"[[planes]]\npoint = [0, 0, {-top - 0.002}]\n"
    if p["support"] in ("fixed_box", "both"):
        text += ("[[bodies]]\nname = \"support\"\nfixed = true\n"
                 f"shape = {{ type = \"box\", size = [0.04, 0.2, 0.04] }}\n"
                 f"position = [{size[0] / 2 - 0.01}, 0.0, {-top - 0.02}]\n")
    if p["projectile"] != "none":
        shape = ("{ type = \"sphere\", radius = 0.012 }" if p["projectile"] == "sphere"
                 else "{ type = \"box\", size = [0.02, 0.02, 0.02] }")
        text += (f"[[bodies]]\nname = \"projectile\"\nshape = {shape}\ndensity = 7800.0\n"
                 f"position = [{ox}, {oy}, {top + 0.0125}]\nvelocity = [0.0, 0.0, {-p['speed']}]\n")
    text += (f"[[bodies]]\nname = \"target\"\nmodel = \"fem\"\n"
             f"shape = {{ type = \"box\", size = [{size[0]}, {size[1]}, {size[2]}], "
             f"resolution = {p['resolution']:.4f} }}\n"
             f"young = {p['young']}\npoisson = 0.22\ndensity = 2500.0\n"
             f"fracture_stress = {p['fracture_stress']}\norder = {p['order']}\n"
             f"frame = \"{p['frame']}\"\nfragment_model = \"{p['fragment_model']}\"\n"
             f"rigid_fragment_tets = {p['rigid_fragment_tets']}\n"
             f"max_cracks_per_step = {p['max_cracks']}\n")
    if p["projectile"] == "none":        # no projectile: the body itself moves into its anchors' pull
        text += f"velocity = [0.0, 0.0, {-p['speed']}]\n"
    return text + _anchor_boxes(p["anchors"], size)


def run_scene(p):
    """Run the scene of parameters ``p``; returns the simulation. Raises AssertionError (with the
    scene) when the run ended in an exception other than a divergence that names its body."""
    text = scene_toml(p)
    sim = Simulation(parse_scene(tomllib.loads(text), "fuzz", Path(".")))
    try:
        sim.run(progress=False, log=lambda message: None)
    except StepFailure as failure:
        raise AssertionError(f"{failure}\nscene:\n{text}") from failure.error
    except InstabilityError as error:
        assert error.body in sim.body_names, f"{error}\nscene:\n{text}"
    return sim


@settings(max_examples=40, deadline=None, derandomize=True, database=None,
          suppress_health_check=list(HealthCheck))
@given(fracture_scenes())
def test_random_fracture_scenes_never_end_in_an_exception(p):
    run_scene(p)
