"""The validated scene as frozen dataclasses; their docstrings list every field, from the schema."""
from dataclasses import dataclass, field as dataclass_field
from pathlib import Path

from .describe import allowed_text, default_text
from .schema import (ANCHOR, AUTO, BODY, DAMPING, LOAD, PLANE, SHAPE, SIMULATION, SOLVER, UNBREAKABLE,
                     field_default)

Vec3 = tuple[float, float, float]
Box = tuple[Vec3, Vec3]


@dataclass(frozen=True)
class Solver:
    iterations: int = field_default(SOLVER, "iterations")
    deformable_iterations: int = field_default(SOLVER, "deformable_iterations")
    contact_margin: float = field_default(SOLVER, "contact_margin")
    hold_resting: bool = field_default(SOLVER, "hold_resting")
    linear_solver: str = field_default(SOLVER, "linear_solver")
    corotated_solver: str = field_default(SOLVER, "corotated_solver")


@dataclass(frozen=True)
class Simulation:
    name: str
    duration: float = field_default(SIMULATION, "duration")
    dt: float = field_default(SIMULATION, "dt")
    gravity: Vec3 = field_default(SIMULATION, "gravity")
    output_fps: float = field_default(SIMULATION, "output_fps")
    resolve_impacts: bool = field_default(SIMULATION, "resolve_impacts")
    solver: Solver = Solver()


@dataclass(frozen=True)
class Plane:
    point: Vec3 = field_default(PLANE, "point")
    normal: Vec3 = field_default(PLANE, "normal")
    friction: float = field_default(PLANE, "friction")
    restitution: float = field_default(PLANE, "restitution")


@dataclass(frozen=True)
class Shape:
    type: str
    size: Vec3 | None = None
    radius: float | None = None
    height: float | None = None
    resolution: float | None = None
    refine: int = 1


@dataclass(frozen=True)
class Damping:
    mass: float = field_default(DAMPING, "mass")
    stiffness: float = field_default(DAMPING, "stiffness")


@dataclass(frozen=True)
class Auto:
    rigidify_strain: float = field_default(AUTO, "rigidify_strain")
    elastify_strain: float = field_default(AUTO, "elastify_strain")
    window: int = field_default(AUTO, "window")
    fracture_margin: float = field_default(AUTO, "fracture_margin")


@dataclass(frozen=True)
class Anchor:
    box: Box
    velocity: Vec3 = field_default(ANCHOR, "velocity")


@dataclass(frozen=True)
class Load:
    box: Box
    force: Vec3


@dataclass(frozen=True)
class Unbreakable:
    box: Box


@dataclass(frozen=True)
class Body:
    name: str
    model: str = field_default(BODY, "model")
    shape: Shape | None = None
    mesh: Path | None = None
    density: float = field_default(BODY, "density")
    position: Vec3 = field_default(BODY, "position")
    orientation: tuple[float, float, float, float] = field_default(BODY, "orientation")
    velocity: Vec3 = field_default(BODY, "velocity")
    angular_velocity: Vec3 = field_default(BODY, "angular_velocity")
    friction: float = field_default(BODY, "friction")
    restitution: float = field_default(BODY, "restitution")
    fixed: bool = field_default(BODY, "fixed")
    young: float | None = None
    poisson: float = field_default(BODY, "poisson")
    damping: Damping = Damping()
    frame: str = field_default(BODY, "frame")
    order: int = field_default(BODY, "order")
    mass_matrix: str = field_default(BODY, "mass_matrix")
    integrator: str = field_default(BODY, "integrator")
    anchors: tuple[Anchor, ...] = ()
    loads: tuple[Load, ...] = ()
    yield_stress: float | None = None
    plastic_update_strain: float = field_default(BODY, "plastic_update_strain")
    max_plastic_strain: float | None = None
    fracture_stress: float | None = None
    tearing_strain: float | None = None
    fragment_model: str = field_default(BODY, "fragment_model")
    rigid_fragment_tets: int = field_default(BODY, "rigid_fragment_tets")
    max_cracks_per_step: int = field_default(BODY, "max_cracks_per_step")
    unbreakable: tuple[Unbreakable, ...] = ()
    auto: Auto = Auto()


@dataclass(frozen=True)
class Scene:
    """A validated scene.

    Attributes:
        name: scene name (``simulation.name``), used for the output folder.
        source_path: the scene file as given to :func:`load_scene`.
        simulation: time stepping settings.
        planes: static half-spaces.
        bodies: bodies in file order.
        raw: the parsed TOML as a dict, for writing into ``summary.json``.
    """
    name: str
    source_path: Path
    simulation: Simulation
    planes: tuple[Plane, ...]
    bodies: tuple[Body, ...]
    raw: dict = dataclass_field(default_factory=dict, repr=False)


def _attribute_doc(section, summary, extra=""):
    lines = [summary, "", "Attributes (SI units; defaults as in the scene file):"]
    for f in section.fields:
        unit = f" [{f.unit}]" if f.unit else ""
        allowed = allowed_text(f)
        allowed = f"; allowed: {allowed}" if allowed else ""
        fem = " (FEM only)" if f.fem else ""
        lines.append(f"    {f.name}{unit}: {f.doc}{fem} Default: {default_text(f)}{allowed}.")
    return "\n".join(lines) + extra


Solver.__doc__ = _attribute_doc(SOLVER, "Solver settings (``[simulation.solver]``).")
Simulation.__doc__ = _attribute_doc(SIMULATION, "Time stepping settings (``[simulation]``).")
Plane.__doc__ = _attribute_doc(PLANE, "A static half-space (``[[planes]]``); ``normal`` is a unit vector.")
Shape.__doc__ = _attribute_doc(SHAPE, "An analytic body shape; fields a type does not use are None.")
Damping.__doc__ = _attribute_doc(DAMPING, "Rayleigh damping of an FEM body.")
Auto.__doc__ = _attribute_doc(AUTO, "When an auto body switches between rigid and FEM.")
Anchor.__doc__ = _attribute_doc(ANCHOR, "A held region of an FEM body; ``box`` is ``(min, max)``.")
Load.__doc__ = _attribute_doc(LOAD, "A loaded region of an FEM body; ``box`` is ``(min, max)``.")
Unbreakable.__doc__ = _attribute_doc(UNBREAKABLE, "A region of an FEM body that never cracks.")
Body.__doc__ = _attribute_doc(BODY, "A body (``[[bodies]]``).", "\n    ``mesh`` is the resolved absolute "
                              "path; ``orientation`` is a unit quaternion (w, x, y, z).")
