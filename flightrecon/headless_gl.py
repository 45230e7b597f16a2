"""Offscreen OpenGL for MuJoCo's camera on machines without a display.

MuJoCo binds its OpenGL backend when it is first imported, so the package chooses one before any
submodule imports mujoco: EGL where libEGL is installed, else OSMesa where libOSMesa is, else EGL
(whose import then fails). A user's own MUJOCO_GL wins. `check_mujoco_import` turns the import's
obscure failure when the backend's library is missing into one message that says what to install.
"""

from __future__ import annotations

import ctypes.util
import os
from typing import Callable

from flightrecon.errors import FlightReconError

# MUJOCO_GL value, the library it loads, the Debian/Ubuntu package that installs it
BACKENDS = (("egl", "EGL", "libegl1"), ("osmesa", "OSMesa", "libosmesa6"))


def choose_backend(find_library: Callable[[str], str | None] = ctypes.util.find_library) -> str:
    """The first backend whose library is installed (EGL, then OSMesa); EGL if neither is."""
    for backend, library, _ in BACKENDS:
        if find_library(library):
            return backend
    return BACKENDS[0][0]


def set_default_backend() -> None:
    """MUJOCO_GL (and PyOpenGL's platform) for headless rendering, unless the user set them."""
    os.environ.setdefault("MUJOCO_GL", choose_backend())
    os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])


def check_mujoco_import() -> None:
    """Import mujoco; a failure of its OpenGL backend becomes one FlightReconError naming the fix."""
    try:
        import mujoco  # noqa: F401
    except Exception as exc:  # PyOpenGL fails with AttributeError/ImportError when the library is missing
        backend = os.environ.get("MUJOCO_GL", "")
        raise FlightReconError(
            f"MuJoCo cannot load its OpenGL backend MUJOCO_GL={backend!r} ({type(exc).__name__}: {exc}). "
            "Headless rendering needs EGL (Debian/Ubuntu: apt-get install libegl1 libgl1) or OSMesa "
            "(apt-get install libosmesa6; then MUJOCO_GL=osmesa, which flightrecon picks by itself when EGL is "
            "missing); on a desktop with a display, MUJOCO_GL=glfw") from None
