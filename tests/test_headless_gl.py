"""Headless OpenGL: EGL where installed, else OSMesa; a backend that cannot load says what to install."""

import ctypes.util
import os
import subprocess
import sys

import pytest

from flightrecon.headless_gl import choose_backend


def test_egl_first_then_osmesa():
    assert choose_backend(lambda lib: "lib" + lib + ".so") == "egl"
    assert choose_backend(lambda lib: "libOSMesa.so" if lib == "OSMesa" else None) == "osmesa"
    assert choose_backend(lambda lib: None) == "egl"  # neither: EGL, whose import then says what to install


def test_the_package_keeps_a_users_backend_and_picks_egl_here():
    code = "import flightrecon, os; print(os.environ['MUJOCO_GL'])"
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == choose_backend()
    env["MUJOCO_GL"] = "glfw"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "glfw"


def test_a_backend_that_cannot_load_names_the_packages_to_install(tmp_path):
    """A backend whose library is absent (OSMesa on these machines) fails mujoco's import; the CLI says
    what to install in one line instead of PyOpenGL's AttributeError."""
    if ctypes.util.find_library("OSMesa"):
        pytest.skip("OSMesa is installed here: its backend loads")
    env = dict(os.environ, MUJOCO_GL="osmesa", PYOPENGL_PLATFORM="osmesa")
    r = subprocess.run([sys.executable, "-m", "flightrecon.cli", "fly", "demo", "--set", "budget.frames=1", "--out",
                        str(tmp_path / "run")], env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr[-2000:]
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "MUJOCO_GL='osmesa'" in lines[0] and "libosmesa6" in lines[0] and "libegl1" in lines[0]
