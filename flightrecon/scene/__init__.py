"""Scenes: mesh loading (Replica PLY, PLY, OBJ, GLB), procedural Replica-format scenes, baking."""

from flightrecon.scene.loaders import load_scene
from flightrecon.scene.source import scene_from_config
from flightrecon.scene.types import Scene

__all__ = ["Scene", "load_scene", "scene_from_config"]
