"""The up direction of scan-like meshes (tests/scan_corpus.py: TSDF-fused hand-held scans of the eight
procedural scenes, stored in a first camera's frame, y-up, -y-up or z-up, with holes, partial or no
ceilings, low walls, furniture, millimetres): right within 2 degrees with the right sign on every
mesh, confident (and so applied) on at least 90% of them, never confidently wrong. The truth is each
scan's sidecar, which the estimator never reads. On failure the table of every mesh (error,
confidence, reason) is printed."""

import math

import numpy as np
import pytest

from flightrecon.cli import main as cli_main
from flightrecon.errors import SceneError
from flightrecon.scenario import load_config
from flightrecon.scene.gravity import estimate_up
from flightrecon.scene.loaders import load_scene
from flightrecon.scene.source import scene_from_config
from scan_corpus import scan_corpus


@pytest.fixture(scope="module")
def table() -> list[dict]:
    rows = []
    for r in scan_corpus():
        raw = load_scene(r.path, up_axis="z", unit_scale=r.meters_per_unit)  # the file's own axes, in metres
        est = estimate_up(raw.vertices, raw.faces)
        truth = np.asarray(r.up, float) / np.linalg.norm(r.up)
        cos = float(np.clip(est.up @ truth, -1.0, 1.0))
        rows.append({"mesh": r.path.name, "error_deg": math.degrees(math.acos(abs(cos))), "sign": cos > 0,
                     "confident": est.confident, "reason": est.reason, "record": r})
    print("\n".join(f"{x['mesh']:40s} {x['error_deg']:6.2f} deg  sign {'right' if x['sign'] else 'WRONG'}  "
                    f"{'confident' if x['confident'] else 'uncertain: ' + x['reason']}" for x in rows))
    return rows


@pytest.mark.slow
def test_the_up_axis_and_sign_are_right_on_every_scan(table):
    wrong = [x["mesh"] for x in table if x["error_deg"] > 2.0 or not x["sign"]]
    assert len(table) >= 40 and not wrong, wrong


@pytest.mark.slow
def test_confident_on_nine_in_ten_and_never_confidently_wrong(table):
    confident = [x for x in table if x["confident"]]
    assert len(confident) >= math.ceil(0.9 * len(table)), [(x["mesh"], x["reason"]) for x in table
                                                            if not x["confident"]]
    assert all(x["error_deg"] <= 2.0 and x["sign"] for x in confident)


@pytest.mark.slow
def test_a_confident_estimate_is_applied_with_the_floor_at_the_bottom(table):
    """Loaded with every scene key at its default, a confidently estimated scan is level: the truth's
    up comes out as world +z and its floor at the bottom of the room."""
    for x in [x for x in table if x["confident"]][::5]:
        r = x["record"]
        cfg = load_config(None, [f"scene.path={r.path}", f"scene.unit_scale={r.meters_per_unit}"])
        scene = scene_from_config(cfg.scene)
        R = np.asarray(scene.meta["up_axis"]["rotation"])
        up_world = R @ (np.asarray(r.up, float) / np.linalg.norm(r.up))
        assert up_world[2] > math.cos(math.radians(2.0)), x["mesh"]
        floor_world = r.floor * r.meters_per_unit
        heights = scene.vertices[:, 2]
        assert abs(np.percentile(heights, 1) - floor_world) < 0.15, x["mesh"]


@pytest.mark.slow
def test_a_scan_that_cannot_be_oriented_is_refused_and_flies_level_with_the_flag_it_names(table, tmp_path, capsys):
    """An uncertain estimate of a scan kept in a tilted camera's frame (room1-seed4-camera.obj: its
    floor 40 deg off the file's z) is neither applied nor replaced by the file's z: `fly` stops before
    take-off with exit 2, naming the estimate and scene.up_vector. Set as the message says, the scan
    loads with the truth's up as world +z. Uncertain scans whose file z is their up still load."""
    refused = [x for x in table if not x["confident"] and abs(x["record"].up[2]) / np.linalg.norm(x["record"].up)
               < math.cos(math.radians(10.0))]
    assert refused, "the corpus has no uncertain scan in a tilted frame"
    for x in refused:
        r = x["record"]
        code = cli_main(["fly", "default", "--quiet", "--out", str(tmp_path / r.path.stem), "--set",
                         f"scene.path={r.path}", "--set", f"scene.unit_scale={r.meters_per_unit}"])
        err = capsys.readouterr().err
        assert code == 2 and "cannot tell which way is up" in err and str(r.path) in err, err
        assert not (tmp_path / r.path.stem / "frames.csv").exists()  # nothing flown
        vector = err.split("scene.up_vector = [")[1].split("]")[0]
        cfg = load_config(None, [f"scene.path={r.path}", f"scene.unit_scale={r.meters_per_unit}",
                                 f"scene.up_vector=[{vector}]"])
        scene = scene_from_config(cfg.scene)
        up_world = np.asarray(scene.meta["up_axis"]["rotation"]) @ (np.asarray(r.up, float) / np.linalg.norm(r.up))
        assert up_world[2] > math.cos(math.radians(2.0)), r.path.name
    with pytest.raises(SceneError, match="scene.up_vector"):
        load_scene(refused[0]["record"].path, up_axis="auto", unit_scale=refused[0]["record"].meters_per_unit)
