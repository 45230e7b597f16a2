"""`flightrecon scene make|info|tour` on real files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from flightrecon.cli import main as cli_main
from flightrecon.geometry import intrinsics
from flightrecon.scene import load_scene


@pytest.mark.slow
def test_make_then_info_describes_the_written_scene(tmp_path, capsys):
    assert cli_main(["scene", "make", "room2", "--out", str(tmp_path / "room2")]) == 0
    capsys.readouterr()
    mesh = tmp_path / "room2" / "mesh.ply"
    assert cli_main(["scene", "info", str(mesh), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    scene = load_scene(mesh)
    assert info["vertices"] == len(scene.vertices) and info["triangles"] == len(scene.faces)
    assert info["quads"] * 2 == len(scene.faces)
    assert info["appearance"] == "vertex colors" and info["file_up_axis"] == "z"
    np.testing.assert_allclose(info["bounds_min"], scene.bounds[0], atol=1e-4)
    assert info["enclosed"] and info["free_volume_m3"] > 10
    assert cli_main(["scene", "info", str(mesh)]) == 0
    text = capsys.readouterr().out
    assert "free volume" in text and "vertex colors" in text


@pytest.mark.slow
def test_tour_writes_rgbd_views(tmp_path):
    import cv2

    out = tmp_path / "tour"
    assert cli_main(["scene", "tour", "room0", "--out", str(out), "--views", "2", "--width", "160",
                     "--height", "120", "--cache-dir", str(tmp_path / "cache")]) == 0
    views = json.loads((out / "views.json").read_text())
    np.testing.assert_allclose(views["K"], intrinsics(160, 120, 90.0))
    assert len(views["frames"]) == 2
    for f in views["frames"]:
        rgb = cv2.imread(str(out / f["rgb"]))
        depth = cv2.imread(str(out / f["depth_mm"]), cv2.IMREAD_UNCHANGED)
        assert rgb.shape == (120, 160, 3) and rgb.std() > 5
        assert depth.dtype == np.uint16 and (depth > 0).all() and depth.max() < 10000


def test_unknown_scene_name_is_a_user_error(tmp_path, capsys):
    assert cli_main(["scene", "make", "kitchen7", "--out", str(tmp_path)]) == 2
    assert "kitchen7" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["--debug", "scene", "make", "kitchen7"], ["scene", "make", "kitchen7", "--debug"]])
def test_debug_before_or_after_the_subcommand_shows_the_traceback(tmp_path, argv):
    from flightrecon.errors import FlightReconError

    with pytest.raises(FlightReconError, match="kitchen7"):
        cli_main(argv + ["--out", str(tmp_path)])
