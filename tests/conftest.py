"""Shared pytest set-up: the package sets MUJOCO_GL before any test imports mujoco."""

import flightrecon  # noqa: F401  (sets MUJOCO_GL=egl)
