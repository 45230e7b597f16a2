"""Procedural scenes: deterministic bytes, rooms of the promised size, closed, furnished, varied."""

from __future__ import annotations

import numpy as np
import pytest

from flightrecon.errors import SceneError
from flightrecon.planning.poses import start_position
from flightrecon.scene import load_scene, scene_from_config
from flightrecon.scene.procedural import SCENE_NAMES, make_scene
from flightrecon.scene.source import write_scene_dir
from flightrecon.scene.stats import free_space


def test_same_seed_same_bytes_other_seed_other_scene(tmp_path):
    a = write_scene_dir(make_scene("room0", 0), tmp_path / "a").read_bytes()
    b = write_scene_dir(make_scene("room0", 0), tmp_path / "b").read_bytes()
    c = write_scene_dir(make_scene("room0", 1), tmp_path / "c").read_bytes()
    assert a == b
    assert a != c
    assert (tmp_path / "a" / "scene_meta.json").read_bytes() == (tmp_path / "b" / "scene_meta.json").read_bytes()


@pytest.mark.parametrize("name", SCENE_NAMES)
def test_every_named_scene_is_a_closed_furnished_room(name):
    s = make_scene(name)
    (x0, y0, z0), (x1, y1, z1) = s.meta["room_box"]
    assert 3.0 <= min(x1 - x0, y1 - y0) and max(x1 - x0, y1 - y0) <= 8.0
    assert 2.5 <= z1 - z0 <= 3.0
    assert 50_000 < len(s.faces) <= 400_000  # fine enough for patterns, light enough to load fast
    assert np.isfinite(s.vertices).all()
    kinds = {o["kind"] for o in s.meta["openings"]}
    assert "door" in kinds and "window" in kinds
    # the take-off column is free of geometry
    lo, hi = np.asarray(s.meta["free_box"])
    inside = np.all((s.vertices > lo + 1e-6) & (s.vertices < hi - 1e-6), axis=1)
    assert not inside.any()
    # furniture: geometry inside the room well above the floor and away from the walls
    v = s.vertices
    interior = (v[:, 0] > x0 + 0.35) & (v[:, 0] < x1 - 0.35) & (v[:, 1] > y0 + 0.35) & (v[:, 1] < y1 - 0.35)
    assert (interior & (v[:, 2] > 0.3) & (v[:, 2] < z1 - 0.3)).sum() > 1000
    # rich appearance: many distinct colors, strong local contrast somewhere
    assert len(np.unique(s.vertex_colors, axis=0)) > 2000
    assert s.vertex_colors.astype(float).std() > 30


@pytest.mark.parametrize("name", ["office0", "room0"])
def test_scene_is_enclosed(name):
    """Empty space inside is not connected to the outside: depth can have no holes to it."""
    s = make_scene(name)
    fs = free_space(s, start_position(s, 1.2), pitch=0.1)
    (x0, y0, z0), (x1, y1, z1) = s.meta["room_box"]
    assert fs["enclosed"]
    assert 0.5 * (x1 - x0) * (y1 - y0) * (z1 - z0) < fs["free_volume_m3"] < (x1 - x0) * (y1 - y0) * (z1 - z0)


def test_recess_opens_a_wall():
    s = make_scene("office0")
    door = next(o for o in s.meta["openings"] if o["kind"] == "door")
    a, b = np.asarray(door["start"]), np.asarray(door["end"])
    mid = (a + b) / 2
    # a recess: surface exists beyond the wall's inner plane at the door's middle
    along = (b - a) / np.linalg.norm(b - a)
    outward = np.cross(along, [0, 0, -1.0])
    near = np.abs((s.vertices - mid) @ along) < 0.2
    beyond = ((s.vertices - mid) @ outward) > 0.1
    low = s.vertices[:, 2] < 1.5
    assert (near & beyond & low).sum() > 10


def test_a_screen_on_a_cabinet_narrower_than_it_is_built():
    # office4 seed 3 draws a monitor wider than the cabinet it stands on (it used to fail to build)
    scene = make_scene("office4", 3)
    assert len(scene.faces) > 1000


def test_unknown_name_is_a_scene_error():
    with pytest.raises(SceneError, match="office9"):
        make_scene("office9")


def test_scene_from_config_caches_in_replica_format(tmp_path):
    from flightrecon.scenario import load_config

    cfg = load_config(None, [f'scene.cache_dir="{tmp_path}"', 'scene.name="room1"'])
    first = scene_from_config(cfg.scene)
    second = scene_from_config(cfg.scene)  # now read back from the cached mesh.ply
    assert first.source == second.source and second.source.name == "mesh.ply"
    np.testing.assert_array_equal(first.vertices, second.vertices)
    np.testing.assert_array_equal(first.vertex_colors, second.vertex_colors)
    assert second.meta["free_box"] == first.meta["free_box"]
    # a user path wins over the procedural name
    user = load_config(None, [f'scene.path="{second.source}"', 'scene.name="mine"'])
    assert scene_from_config(user.scene).name == "mine"
    assert load_scene(second.source).meta["spawn"] == first.meta["spawn"]
