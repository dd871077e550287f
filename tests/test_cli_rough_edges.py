"""What a new user meets on the command line: clear messages and exit code 2, never a traceback."""
import pytest

from hybrid.app.cli import main


def test_out_below_a_file_is_refused_naming_the_file(tmp_path, capsys):
    blocker = tmp_path / "notes.txt"
    blocker.write_text("mine")
    assert main(["run", "default", "--out", str(blocker / "sub"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"{blocker} is a file" in err and "Traceback" not in err
    assert blocker.read_text() == "mine"


def test_render_size_must_be_drawable(tmp_path, capsys):
    assert main(["render", str(tmp_path), "--size", "0", "-5"]) == 2
    assert "at least 16 pixels" in capsys.readouterr().err


def test_help_lists_every_render_field_and_version_is_printed(capsys):
    with pytest.raises(SystemExit):
        main(["render", "--help"])
    text = capsys.readouterr().out
    assert all(f in text for f in ("von_mises", "principal_stress", "plastic_strain"))
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0 and capsys.readouterr().out.startswith("hybrid ")


def test_a_rigid_body_starting_inside_a_deformable_one_is_warned_about():
    import tomllib
    from pathlib import Path

    from hybrid import Simulation
    from hybrid.app.scene import parse_scene
    text = """
[simulation]
dt = 0.001
[[bodies]]
name = "block"
model = "fem"
shape = { type = "box", size = [0.2, 0.2, 0.2], resolution = 0.1 }
young = 1.0e6
position = [0.0, 0.0, 0.1]
[[bodies]]
name = "stone"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
position = [0.0, 0.0, %s]
"""
    sunk = Simulation(parse_scene(tomllib.loads(text % 0.22), "<test>", Path(".")))   # 3 cm into it
    assert sunk.warnings == ["bodies 'block' and 'stone' overlap at the start"]
    clear = Simulation(parse_scene(tomllib.loads(text % 0.2501), "<test>", Path(".")))
    assert clear.warnings == []
