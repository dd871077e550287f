"""Coupled rigid/FEM stepping, scene files, command line, VTK output and rendering."""
