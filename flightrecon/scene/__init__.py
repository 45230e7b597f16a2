"""Scenes: mesh loading (Replica PLY, PLY, OBJ, GLB), procedural Replica-format scenes, baking."""
