"""Scenes shipped with the package."""
