"""Where the files that ship with flightrecon lie: the scenarios, the quadrotor model and the C++
sources of the rasterizer.

In a checkout they are the repository's top-level folders, the only copy anyone edits. A built
wheel carries copies inside the package (`flightrecon/_data/`, made by setup.py's build step), so
an installed package never reads outside itself; nothing is written there at run time (the
extension builds into the user's cache, `flightrecon.render.extension`).
"""

from __future__ import annotations

from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
SHIPPED = ("scenarios", "models", "csrc")
DATA = "_data"


def resource(name: str) -> Path:
    """The folder `name` (one of SHIPPED): inside the installed package, else the checkout's."""
    if name not in SHIPPED:
        raise ValueError(f"{name!r} is not a shipped folder ({', '.join(SHIPPED)})")
    inside = PACKAGE / DATA / name
    return inside if inside.is_dir() else PACKAGE.parent / name
