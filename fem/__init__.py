"""Tetrahedral finite elements: meshes, assembly, time integration, plasticity, fracture."""
