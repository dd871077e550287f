"""A deformable body struck near its wave speed ``sqrt(E / rho)`` strains of order one: linear
elements turn inside out and a body pressed into it can pass through. The run says so as it
happens (not only a strain note suggesting the corotated frame) and the summary's peaks keep the
count; a blow well below the wave speed inverts nothing."""
import pytest

SCENE = """
[simulation]
duration = 0.006
dt = 1e-4
gravity = [0.0, 0.0, 0.0]
[[bodies]]
name = "rubber"
model = "fem"
shape = {{ type = "sphere", radius = 0.05, resolution = 0.025 }}
position = [-0.051, 0.0, 0.015]
velocity = [{speed}, 0.0, 0.0]
young = 1e6
density = 1000
integrator = "newmark"
[[bodies]]
name = "steel"
shape = {{ type = "sphere", radius = 0.05 }}
position = [0.051, 0.0, -0.015]
velocity = [{minus}, 0.0, 0.0]
density = 7800
"""


@pytest.mark.parametrize("closing", [50.0, 5.0])
def test_a_blow_near_the_wave_speed_is_said_to_turn_elements_inside_out(sim, closing):
    """Rubber (wave speed 31.6 m/s) struck by a steel ball at 50 m/s (strain about v / c = 1.6)
    and at 5 m/s (0.16)."""
    s = sim(SCENE.format(speed=closing / 2, minus=-closing / 2))
    lines = []
    summary = s.run(progress=False, log=lines.append)
    said = [line for line in lines if "turned inside out" in line]
    inverted = summary["peaks"]["rubber"].get("inverted_elements")
    if closing > 31.6:
        assert len(said) == 1 and "'rubber'" in said[0] and "31.6 m/s" in said[0]
        assert inverted is not None and inverted["value"] >= 1 and 0 < inverted["time"] <= 0.006
        assert not any("corotated" in line for line in lines)   # no frame holds that strain
    else:
        assert not said and inverted is None
