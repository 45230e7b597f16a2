"""Importing Open3D, with one clear error when its wheel or a system library it links is missing.

Open3D's wheel links the system libusb-1.0 (and libGL/libEGL/libX11); `make setup` installs
libusb-1.0-0 where apt-get is available. Callers import it on first use, not at module import, so
commands that never need it do not load it.
"""

from __future__ import annotations

import re
from functools import cache

from flightrecon.errors import FlightReconError

# shared libraries Open3D's wheel links, and the Debian/Ubuntu package that provides each
_SYSTEM_PACKAGES = {"libusb-1.0": "libusb-1.0-0", "libGL": "libgl1", "libEGL": "libegl1", "libX11": "libx11-6",
                    "libgomp": "libgomp1", "libc++": "libc++1"}


@cache
def open3d_module():
    """The open3d module, or a FlightReconError that says what is missing and how to install it."""
    try:
        import open3d
    except ModuleNotFoundError as exc:
        if exc.name != "open3d":
            raise
        raise FlightReconError("Open3D (TSDF fusion, exact clearance) is not installed: "
                               "pip install 'open3d-cpu==0.20.0' (or reinstall flightrecon)") from None
    except (ImportError, OSError) as exc:
        lib = re.search(r"(lib[\w.+-]+?\.so[\w.]*)", str(exc))
        name = lib.group(1) if lib else str(exc)
        pkg = next((p for k, p in _SYSTEM_PACKAGES.items() if name.startswith(k + ".so")), None)
        fix = f"install it with `apt-get install -y {pkg}` (or `make setup`)" if pkg else \
            "install the system package that provides it"
        raise FlightReconError(f"Open3D (TSDF fusion, exact clearance) does not import: the system library "
                               f"{name} is missing; {fix}") from None
    open3d.utility.set_verbosity_level(open3d.utility.VerbosityLevel.Error)  # no per-call info/warning lines
    return open3d
