"""Gravity alignment (`scene.up_axis = "auto"`) on real files: a procedural room written tilted,
y-up, upside down or z-up is read back level with its floor at the bottom; manual overrides work;
bad values name their key; a small object is left as it is."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from flightrecon.cli import main as cli_main
from flightrecon.commands.scene import _up_axis_line
from flightrecon.errors import ConfigError, SceneError
from flightrecon.scenario import load_config
from flightrecon.scene import load_scene
from flightrecon.scene.gravity import AXIS_ROTATIONS
from flightrecon.scene.loaders import _Y_UP_TO_Z_UP
from flightrecon.scene.source import write_scene_dir
from flightrecon.scene.stats import summary
from flightrecon.scene.types import Scene
from mesh_scenes import coarse_room

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def room() -> Scene:
    """room0 with 4x coarser surface cells than the generator's (the same room, a tenth of the faces)."""
    return coarse_room()


@pytest.fixture(scope="module")
def files(room, tmp_path_factory) -> dict:
    """room0 written z-up, y-up, upside down and under two random rotations (one a large tilt)."""
    root = tmp_path_factory.mktemp("gravity")
    tilt = Rotation.from_euler("xz", [130.0, 25.0], degrees=True).as_matrix()
    rotations = {"z": np.eye(3), "y": _Y_UP_TO_Z_UP.T, "down": AXIS_ROTATIONS["-z"].T,
                 "random": Rotation.random(random_state=11).as_matrix(), "tilt": tilt}
    out = {}
    for kind, R in rotations.items():  # file = R @ world
        s = Scene(room.name, room.vertices @ R.T, room.faces, vertex_colors=room.vertex_colors,
                  vertex_normals=room.vertex_normals @ R.T, meta=dict(room.meta))
        out[kind] = (write_scene_dir(s, root / kind), R)
    return out


def _floor_vertices(room: Scene) -> np.ndarray:
    """Vertices of the room's floor (z = 0, normal up) in the generator's world."""
    return np.flatnonzero((np.abs(room.vertices[:, 2]) < 1e-9) & (room.vertex_normals[:, 2] > 0.999))


@pytest.mark.parametrize("kind", ["random", "tilt"])
def test_a_rotated_room_is_leveled_with_its_floor_at_the_bottom(room, files, kind, caplog):
    path, _ = files[kind]
    with caplog.at_level(logging.WARNING, logger="flightrecon.scene.loaders"):
        s = load_scene(path, up_axis="auto")
    floor = _floor_vertices(room)
    normals = s.vertex_normals[floor]
    angle = np.degrees(np.arccos(np.clip(normals[:, 2] / np.linalg.norm(normals, axis=1), -1, 1)))
    assert angle.max() < 2.0
    z = s.vertices[:, 2]
    assert np.ptp(z[floor]) < 0.02  # level
    assert (z[floor].mean() - z.min()) / np.ptp(z) < 0.1  # at the bottom: not the ceiling
    est = s.meta["up_axis"]["estimate"]
    assert s.meta["up_axis"]["mode"] == "auto" and est["confidence"] == "confident"
    assert est["floor_share"] > 0.1 and est["wall_share"] > 0.3 and est["floor_spread_deg"] < 1.0
    # the walls run along the world axes; the sidecar's frame keys no longer fit and are dropped
    wall = s.vertex_normals[np.abs(room.vertex_normals[:, 0]) > 0.999]
    assert np.abs(wall[:, :2]).max(axis=1).min() > math.cos(math.radians(2.0))
    assert "floor_z" not in s.meta and "free_box" not in s.meta
    assert "dropped the metadata" in caplog.text


def test_z_up_and_y_up_files_need_no_flag(files):
    z_path, y_path = files["z"][0], files["y"][0]
    as_z, auto_z = load_scene(z_path, up_axis="z"), load_scene(z_path, up_axis="auto")
    np.testing.assert_array_equal(auto_z.vertices, as_z.vertices)  # exactly identity
    np.testing.assert_array_equal(auto_z.vertex_normals, as_z.vertex_normals)
    assert auto_z.source_up_axis == "z" and auto_z.meta["floor_z"] == as_z.meta["floor_z"] == 0.0
    assert auto_z.meta["up_axis"]["estimate"]["snapped"] == "z"
    as_y, auto_y = load_scene(y_path, up_axis="y"), load_scene(y_path, up_axis="auto")
    np.testing.assert_array_equal(auto_y.vertices, as_y.vertices)
    assert auto_y.source_up_axis == "y"
    np.testing.assert_allclose(auto_y.vertices, as_z.vertices, atol=1e-6)


def test_an_upside_down_file_is_turned_over(files):
    s = load_scene(files["down"][0], up_axis="auto")
    assert s.source_up_axis == "-z"
    np.testing.assert_array_equal(s.vertices, load_scene(files["z"][0]).vertices)


def test_explicit_up_vector_and_rotation(files, room):
    y_path = files["y"][0]
    by_vector = load_scene(y_path, up_axis="z", up_vector=[0, 2.5, 0])  # overrides up_axis, any length
    np.testing.assert_array_equal(by_vector.vertices, load_scene(y_path, up_axis="y").vertices)
    assert by_vector.meta["up_axis"]["mode"] == "vector"
    path, R = files["random"]
    tilted = load_scene(path, up_axis="z", up_vector=(R @ [0.0, 0.0, 1.0]).tolist())
    up = tilted.vertex_normals[_floor_vertices(room)]
    assert (up[:, 2] / np.linalg.norm(up, axis=1)).min() > math.cos(math.radians(0.01))
    turned = load_scene(files["z"][0], up_axis="z", rotation_deg=[0, 0, 90])
    v = room.vertices  # a quarter turn about z: (x, y, z) -> (-y, x, z)
    np.testing.assert_allclose(turned.vertices, np.column_stack([-v[:, 1], v[:, 0], v[:, 2]]), atol=1e-5)
    assert "floor_z" not in turned.meta and turned.meta["up_axis"]["rotation_deg"] == [0.0, 0.0, 90.0]


def test_bad_values_name_their_key():
    for kwargs, key in (({"up_vector": [0, 0, 0]}, "scene.up_vector"), ({"up_vector": [1, 2]}, "scene.up_vector"),
                        ({"rotation_deg": [1, 2]}, "scene.rotation_deg"), ({"up_axis": "x"}, "scene.up_axis"),
                        ({"up_vector": [0, float("nan"), 1]}, "scene.up_vector")):
        with pytest.raises(SceneError, match=key.replace(".", r"\.")) as exc:
            load_scene(DATA / "two_quads_ascii.ply", **kwargs)
        assert "two_quads_ascii.ply" in str(exc.value)
    for text, key in (("scene.up_vector=[0, 0, 0]", "scene.up_vector"), ("scene.up_vector=[1, 2]", "scene.up_vector"),
                      ("scene.rotation_deg=[1, 2]", "scene.rotation_deg"), ("scene.rotation_deg=[]", "scene.rotation_deg"),
                      ('scene.up_vector=["a", 1, 2]', "scene.up_vector"), ('scene.up_axis="x"', "scene.up_axis")):
        with pytest.raises(ConfigError, match=f"'{key}'"):
            load_config(None, [text])
    cfg = load_config(None, ["scene.up_vector=[0, 1, 0]", "scene.rotation_deg=[0, 0, 90]"]).scene
    assert cfg.up_vector == [0.0, 1.0, 0.0] and cfg.rotation_deg == [0.0, 0.0, 90.0]
    assert load_config(None).scene.up_axis == "auto" and load_config(None).scene.up_vector == []


def test_a_small_object_is_uncertain_and_left_as_it_is(caplog):
    with caplog.at_level(logging.WARNING, logger="flightrecon.scene.loaders"):
        s = load_scene(DATA / "two_quads_ascii.ply", up_axis="auto")
    np.testing.assert_array_equal(s.vertices, load_scene(DATA / "two_quads_ascii.ply").vertices)
    assert s.source_up_axis == "z" and s.meta["up_axis"]["estimate"]["confidence"] == "uncertain"
    assert "uncertain" in caplog.text and "scene.up_vector" in caplog.text


def test_scene_info_prints_the_estimate(files, capsys):
    path, R = files["tilt"]
    assert cli_main(["scene", "info", str(path)]) == 0  # auto is the default
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("up axis"))
    assert "auto: file (" in line and "-> world z, confident (floor" in line and "spread" in line
    info = summary(load_scene(path, up_axis="auto"))
    assert info["up_axis_mode"] == "auto" and info["up_estimate"]["confidence"] == "confident"
    assert np.degrees(np.arccos(np.dot(info["up_vector"], R @ [0.0, 0.0, 1.0]))) < 0.1
    assert abs(info["floor_z"]) < 0.02  # the floor found in the leveled geometry
    json.dumps(info)
    assert _up_axis_line(summary(load_scene(path, up_axis="z"))) == "file z -> world z"
