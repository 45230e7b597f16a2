"""Simulation: MuJoCo world assembly, quadrotor plant, RGB-D camera, flight cycle and safety monitors.

Importing it imports mujoco first, so a missing OpenGL library fails here with what to install."""

from flightrecon.headless_gl import check_mujoco_import as _check_mujoco_import

_check_mujoco_import()
