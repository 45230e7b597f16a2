"""FlightRecon: active scene reconstruction with a simulated quadrotor.

MuJoCo renders offscreen only through EGL on the CPU-only machines we target (osmesa is absent),
and the backend is chosen when mujoco is first imported, so the package sets it before any
submodule can import mujoco. A user's own MUJOCO_GL wins.
"""

import os as _os

_os.environ.setdefault("MUJOCO_GL", "egl")
_os.environ.setdefault("PYOPENGL_PLATFORM", _os.environ["MUJOCO_GL"])

__version__ = "0.1.0"
