"""Drake's side of benchmarks/drake_compare.py: run one case with Drake's deformable FEM.

Runs in Drake's own interpreter (Python >= 3.12 with ``pip install drake``; see
benchmarks/README.md), started by drake_compare.py as

    DRAKE_PYTHON benchmarks/drake_driver.py CASE.json RESULT.json

CASE.json (written by drake_compare.py): ``mesh`` (a legacy .vtk tet mesh in world coordinates),
``material`` (``linear``, ``linear_corotated``, ``corotated``), ``young`` Pa, ``poisson``,
``density`` kg/m^3, ``mass_damping`` 1/s, ``stiffness_damping`` s, ``dt`` s, ``duration`` s,
``sample_every`` (steps between samples of the positions), ``ground`` (friction of a ground
whose top is z = 0, or null), ``box`` (``size`` m, ``mass`` kg, ``position`` m, ``friction``: a
free rigid box, or null), ``clamp_x`` (vertices with x below it are held, or null), ``repeats``.

RESULT.json: ``walls`` and ``cpus`` (wall and process CPU s of the stepping per repeat, the
diagram built outside the timing),
``drake_version``, ``vertex_count``, ``reference`` (the vertices as Drake holds them, to check
the order matches the mesh), ``final`` (vertex positions at the end), ``min_z`` (lowest vertex
z over the samples), ``box_z`` (the box's final height, or null).
"""
import json
import sys
import time

import numpy as np
from pydrake.geometry import AddContactMaterial, Box, GeometryInstance, Mesh, ProximityProperties
from pydrake.math import RigidTransform
from pydrake.multibody.fem import DeformableBodyConfig, MaterialModel
from pydrake.multibody.plant import AddMultibodyPlant, CoulombFriction, MultibodyPlantConfig
from pydrake.multibody.tree import SpatialInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

MATERIALS = {"linear": MaterialModel.kLinear, "linear_corotated": MaterialModel.kLinearCorotated,
             "corotated": MaterialModel.kCorotated}


def rigid_properties(friction):
    """Proximity properties a rigid geometry needs to meet deformable ones: a friction and a
    resolution hint (rigid shapes are tessellated for the deformable contact queries)."""
    props = ProximityProperties()
    AddContactMaterial(friction=CoulombFriction(friction, friction), properties=props)
    props.AddProperty("hydroelastic", "resolution_hint", 0.01)
    return props


def build(case):
    """``(diagram, plant, body id, box body or None)`` of one case."""
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(time_step=case["dt"]), builder)
    if case["ground"] is not None:
        plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform([0.0, 0.0, -1.0]),
                                        Box(2.0, 2.0, 2.0), "ground", rigid_properties(case["ground"]))
    box_body = None
    if case["box"] is not None:
        spec = case["box"]
        inertia = SpatialInertia.SolidBoxWithMass(spec["mass"], *spec["size"])
        box_body = plant.AddRigidBody("box", inertia)
        plant.RegisterCollisionGeometry(box_body, RigidTransform(), Box(*spec["size"]), "box",
                                        rigid_properties(spec["friction"]))
        set_pose = getattr(plant, "SetDefaultFloatingBaseBodyPose", None) or plant.SetDefaultFreeBodyPose
        set_pose(box_body, RigidTransform(spec["position"]))

    config = DeformableBodyConfig()
    config.set_youngs_modulus(case["young"])
    config.set_poissons_ratio(case["poisson"])
    config.set_mass_density(case["density"])
    config.set_mass_damping_coefficient(case["mass_damping"])
    config.set_stiffness_damping_coefficient(case["stiffness_damping"])
    config.set_material_model(MATERIALS[case["material"]])
    instance = GeometryInstance(RigidTransform(), Mesh(case["mesh"]), "body")
    props = ProximityProperties()
    friction = case["ground"] if case["ground"] is not None else 0.5
    AddContactMaterial(friction=CoulombFriction(friction, friction), properties=props)
    instance.set_proximity_properties(props)
    deformable = plant.mutable_deformable_model()
    body_id = deformable.RegisterDeformableBody(instance, config, 1.0)   # the hint is unused for a mesh
    if case["clamp_x"] is not None:
        deformable.SetWallBoundaryCondition(body_id, np.array([case["clamp_x"], 0.0, 0.0]),
                                            np.array([1.0, 0.0, 0.0]))
    plant.Finalize()
    return builder.Build(), plant, body_id, box_body


def run(case):
    """One simulation: ``(wall s, cpu s, final (n, 3), lowest z, box z or None, reference (n, 3))``."""
    diagram, plant, body_id, box_body = build(case)
    simulator = Simulator(diagram)
    simulator.Initialize()
    context = simulator.get_context()
    plant_context = plant.GetMyContextFromRoot(context)
    deformable = plant.deformable_model()
    reference = np.asarray(deformable.GetPositions(plant_context, body_id)).T   # (n, 3)
    steps = int(round(case["duration"] / case["dt"]))
    every = max(1, int(case["sample_every"]))
    lowest = float(reference[:, 2].min())
    start, cpu = time.perf_counter(), time.process_time()
    for k in range(every, steps + every, every):
        simulator.AdvanceTo(min(k, steps) * case["dt"])
        lowest = min(lowest, float(np.asarray(deformable.GetPositions(plant_context, body_id))[2].min()))
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    final = np.asarray(deformable.GetPositions(plant_context, body_id)).T
    box_z = None
    if box_body is not None:
        box_z = float(plant.EvalBodyPoseInWorld(plant_context, box_body).translation()[2])
    return wall, cpu, final, lowest, box_z, reference


def main():
    case_path, result_path = sys.argv[1], sys.argv[2]
    with open(case_path) as f:
        case = json.load(f)
    walls, cpus = [], []
    for _ in range(int(case["repeats"])):
        wall, cpu, final, lowest, box_z, reference = run(case)
        walls.append(wall)
        cpus.append(cpu)
    import pydrake
    version = getattr(pydrake, "__version__", None)
    if version is None:
        from importlib.metadata import version as package_version
        version = package_version("drake")
    result = {"walls": walls, "cpus": cpus, "drake_version": version, "vertex_count": len(final),
              "reference": reference.tolist(), "final": final.tolist(), "min_z": lowest,
              "box_z": box_z}
    with open(result_path, "w") as f:
        json.dump(result, f)


if __name__ == "__main__":
    main()
