"""FlightRecon: active scene reconstruction with a simulated quadrotor.

MuJoCo binds its OpenGL backend when first imported, so the package chooses a headless one (EGL,
else OSMesa; flightrecon.headless_gl) before any submodule can import mujoco. A user's own
MUJOCO_GL wins.
"""

from flightrecon.headless_gl import set_default_backend as _set_default_backend

_set_default_backend()

__version__ = "0.1.0"
