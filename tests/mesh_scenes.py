"""Procedural scenes at test size that several test files load (imported by name, like splat_scenes)."""

import pytest

from flightrecon.scene import procedural
from flightrecon.scene.types import Scene


def coarse_room(name: str = "room0", seed: int = 0) -> Scene:
    """A procedural room with 4x coarser surface cells than the generator's: the same room, a tenth of
    the faces."""
    with pytest.MonkeyPatch.context() as mp:
        for cell in ("CELL_FLOOR", "CELL_WALL", "CELL_CEIL", "CELL_FURN", "CELL_FINE"):
            mp.setattr(procedural, cell, 4 * getattr(procedural, cell))
        return procedural.make_scene(name, seed)
