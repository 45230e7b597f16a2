"""Evaluation that holds on open and holey scans: the room's free space does not leak through a hole
in a wall, an open ceiling or a missing floor patch; evaluation views are kept where their ground
truth sees surface and the rest are counted; no view, however empty or perfect, makes a mean
infinite. Scans are built here: a hand-made room with single-sheet walls (its volume and areas
known by hand) and a procedural room stripped to what a scanner sees (inner faces only), its ceiling
removed, a hole cut in a wall and a patch in its floor, written as a PLY with vertex colors."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
import trimesh

from flightrecon.cli import main as cli_main
from flightrecon.evaluation.views import VALID_DEPTH_SHARE, evaluation_poses, sees_surface, view_metrics
from flightrecon.evaluation.visible_surface import visible_surface
from flightrecon.mapping.image_metrics import psnr
from flightrecon.metric_defs import PSNR_MAX_DB, mean_metrics
from flightrecon.render import RenderOutput
from flightrecon.rig import build_rig
from flightrecon.scenario import load_config
from flightrecon.scene.free_space import room_free_space
from flightrecon.scene.procedural import make_scene
from flightrecon.scene.replica_ply import write_replica_ply
from flightrecon.scene.types import Scene

L, W, H = 4.0, 3.0, 2.5  # the hand-made room, floor at z = 0, centred on the origin
HOLE = 0.6  # side of the square hole in its +x wall, centred at y = 0, z = 1.2
CORRIDOR = 2.0  # floor scanned beyond the +x wall (through a doorway, say): the scan's box holds it
FLOOR_HOLE = 0.5  # side of the square hole in its floor, centred at x = y = -1
TINY = ["camera.width=80", "camera.height=60", "selector.scoring_width=40", "selector.scoring_height=30",
        "mapper.k_new=8", "mapper.k_replay=4", "evaluation.every=1"]


def _sheet(center, u, v, cell: float = 0.05) -> trimesh.Trimesh:
    """A rectangle center +- u +- v as a grid of `cell`-sized squares (so holes can be cut on the grid)."""
    c, u, v = (np.asarray(x, float) for x in (center, u, v))
    n, m = (int(round(2 * np.linalg.norm(a) / cell)) for a in (u, v))
    i, j = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, m + 1), indexing="ij")
    verts = c + i.reshape(-1, 1) * u + j.reshape(-1, 1) * v
    k = (np.arange(n)[:, None] * (m + 1) + np.arange(m)[None, :]).ravel()
    quads = np.stack([k, k + m + 1, k + m + 2, k + 1], axis=1)
    return trimesh.Trimesh(verts, np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]), process=False)


def _cut(mesh: trimesh.Trimesh, lo, hi) -> trimesh.Trimesh:
    """`mesh` less the faces whose centres lie in the box [lo, hi]."""
    c = mesh.triangles_center
    mesh.update_faces(~((c > lo) & (c < hi)).all(axis=1))
    return mesh


def _holey_room(hole: bool = True, ceiling: bool = False) -> Scene:
    """Floor and four single-sheet walls of an L x W x H room, open at the top unless `ceiling`, with a
    HOLE x HOLE hole in the +x wall and a FLOOR_HOLE patch missing in the floor when `hole`, and the
    corridor floor beyond the +x wall."""
    e = 1e-3
    floor = _sheet([0, 0, 0], [L / 2, 0, 0], [0, W / 2, 0])
    wall_x = _sheet([L / 2, 0, H / 2], [0, W / 2, 0], [0, 0, H / 2])
    if hole:
        f = FLOOR_HOLE / 2
        floor = _cut(floor, [-1 - f, -1 - f, -e], [-1 + f, -1 + f, e])
        wall_x = _cut(wall_x, [L / 2 - e, -HOLE / 2, 1.2 - HOLE / 2], [L / 2 + e, HOLE / 2, 1.2 + HOLE / 2])
    parts = [floor, wall_x, _sheet([-L / 2, 0, H / 2], [0, W / 2, 0], [0, 0, H / 2]),
             _sheet([0, W / 2, H / 2], [L / 2, 0, 0], [0, 0, H / 2]),
             _sheet([0, -W / 2, H / 2], [L / 2, 0, 0], [0, 0, H / 2]),
             _sheet([L / 2 + CORRIDOR / 2, 0, 0], [CORRIDOR / 2, 0, 0], [0, W / 2, 0])]
    if ceiling:
        parts.append(_sheet([0, 0, H], [L / 2 + CORRIDOR / 2, 0, 0], [0, W / 2, 0]))
    mesh = trimesh.util.concatenate(parts)
    mesh.merge_vertices()
    return Scene("holey_room", np.asarray(mesh.vertices), np.asarray(mesh.faces, np.int64))


def test_zero_error_scores_the_psnr_cap_and_other_errors_are_unchanged():
    img = torch.rand(12, 16, 3, generator=torch.Generator().manual_seed(0))
    assert float(psnr(img, img)) == pytest.approx(PSNR_MAX_DB, abs=1e-4) == 60.0
    assert math.isfinite(float(psnr(img, img)))
    assert float(psnr(img, img + 1e-5)) == pytest.approx(60.0, abs=1e-4)  # mse 1e-10: past the cap, capped
    assert float(psnr(img * 0, img * 0 + 0.01)) == pytest.approx(40.0, abs=1e-4)  # mse 1e-4: 40 dB, as before
    m = view_metrics(img, torch.full((12, 16, 1), 2.0), torch.ones(12, 16, 1), img, torch.full((12, 16, 1), 2.0))
    assert m["psnr"] == pytest.approx(60.0, abs=1e-4) and m["psnr_covered"] == pytest.approx(60.0, abs=1e-4)


def test_a_view_empty_in_render_and_ground_truth_is_scored_as_documented():
    # nothing rendered, nothing in the ground truth (black, no depth): zero error scores the cap,
    # SSIM of two equal flat images is 1, depth L1 has no valid pixel to differ on (0 cm), and the
    # covered metrics are undefined (NaN), which the mean leaves out
    H_, W_ = 30, 40
    zero3, zero1 = torch.zeros(H_, W_, 3), torch.zeros(H_, W_, 1)
    empty = view_metrics(zero3, zero1, zero1, zero3, zero1)
    assert empty["psnr"] == pytest.approx(60.0, abs=1e-4)
    assert empty["ssim"] == pytest.approx(1.0, abs=1e-9)
    assert empty["depth_l1_cm"] == 0.0 and empty["covered_share"] == 0.0
    assert all(math.isnan(empty[k]) for k in ("psnr_covered", "ssim_covered", "depth_l1_cm_covered"))
    # a second view off by 0.1 everywhere: 20 dB; the mean is (60 + 20) / 2, finite
    gt = torch.full((H_, W_, 3), 0.5)
    other = view_metrics(gt + 0.1, zero1 + 2.0, zero1 + 1.0, gt, zero1 + 2.0)
    assert other["psnr"] == pytest.approx(20.0, abs=1e-4) == other["psnr_covered"]
    mean = mean_metrics([empty, other])
    assert mean["psnr"] == pytest.approx(40.0, abs=1e-4) and mean["psnr_covered"] == pytest.approx(20.0, abs=1e-4)
    assert mean["psnr_covered_views"] == 1 and mean["views"] == 2


def test_a_view_counts_where_its_ground_truth_has_depth_on_90_percent_of_pixels():
    assert VALID_DEPTH_SHARE == 0.9
    depth = np.full((10, 10), 2.0)
    depth[:1] = 0.0  # a tenth without surface (0: nothing within camera.far)
    assert sees_surface(depth)
    depth[1, 0] = np.nan
    assert not sees_surface(depth)  # 89 of 100
    assert not sees_surface(np.zeros((10, 10)))


def test_the_free_space_stays_in_a_room_with_a_wall_hole_a_floor_hole_and_no_ceiling():
    scene = _holey_room()
    free = room_free_space(scene, np.array([0.0, 0.0, 1.2]))
    assert not free.enclosed
    # the room's inner volume less about one voxel where the free space meets each face
    assert 0.95 * L * W * H < free.volume_m3 <= L * W * H
    outside = np.array([[L / 2 + 1.0, 0.0, 1.2],  # beyond the wall hole, above the corridor floor
                        [L / 2 + 0.2, 0.0, 1.2],  # just behind the hole
                        [-1.0, -1.0, -0.05],  # below the floor hole
                        [0.0, 0.0, H + 0.3]])  # above the open top
    assert not free.contains(outside).any()
    inside = np.array([[L / 2 - 0.1, W / 2 - 0.1, 0.1], [-L / 2 + 0.05, 0.0, H - 0.05], [L / 2 - 0.2, 0.0, 1.2]])
    assert free.contains(inside).all()  # corners, the top edge and the front of the hole stay in
    # without closing holes the room would run through the wall hole into the corridor
    assert room_free_space(scene, np.array([0.0, 0.0, 1.2]), hole_radius=0.0).contains(outside[:1]).all()
    # what is visible from the room: its floor and the inner sides of its walls, not the corridor
    vis = visible_surface(scene, free, 100_000)
    inner = L * W - FLOOR_HOLE ** 2 + 2 * (L + W) * H - HOLE ** 2
    assert vis.total_area_m2 == pytest.approx(inner + CORRIDOR * W, rel=1e-6)
    assert vis.visible_area_m2 == pytest.approx(inner, rel=0.03)
    assert (vis.points[:, 0] < L / 2 + 0.01).all()


def test_a_closed_room_is_enclosed_and_its_free_space_exact():
    scene = _holey_room(hole=False, ceiling=True)
    free = room_free_space(scene, np.array([0.0, 0.0, 1.2]))
    assert free.enclosed
    assert 0.95 * L * W * H < free.volume_m3 <= L * W * H
    assert not free.contains(np.array([[L / 2 + 1.0, 0.0, 1.2]])).any()


@pytest.fixture(scope="module")
def room_scan(tmp_path_factory):
    """room0 as a scanner sees it: faces inside its room box only (no outer sides of walls, slabs or
    recesses), no ceiling and walls cut at 2 m, a 0.6 m hole in the +x wall and a 0.5 m floor patch
    missing; written as a PLY with vertex colors, without the generator's metadata."""
    room = make_scene("room0", 0)
    lo, hi = np.asarray(room.meta["room_box"], float)
    c = room.vertices[room.faces].mean(axis=1)
    tol = 0.01
    keep = ((c > lo - tol) & (c < hi + tol)).all(axis=1) & (c[:, 2] < 2.0)
    keep &= ~((np.abs(c[:, 0] - hi[0]) < tol) & (np.abs(c[:, 1]) < 0.3) & (np.abs(c[:, 2] - 1.0) < 0.3))
    floor_patch = (np.abs(c[:, 0] - lo[0] / 2) < 0.25) & (np.abs(c[:, 1] - hi[1] / 2) < 0.25)
    keep &= ~((np.abs(c[:, 2]) < tol) & floor_patch)
    used, faces = np.unique(room.faces[keep], return_inverse=True)
    scan = Scene("room0_scan", room.vertices[used], faces.reshape(-1, 3), vertex_colors=room.vertex_colors[used])
    box_volume = (hi[0] - lo[0]) * (hi[1] - lo[1]) * 2.0  # the room box up to the cut walls' top
    return write_replica_ply(scan, tmp_path_factory.mktemp("scan") / "mesh.ply"), box_volume


def test_scene_info_gives_an_open_scan_a_bounded_free_volume(room_scan, capsys):
    path, box_volume = room_scan
    assert cli_main(["scene", "info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["enclosed"] is False
    assert 0.7 * box_volume < info["free_volume_m3"] < box_volume  # the room up to its walls' top, less furniture
    assert cli_main(["scene", "info", str(path)]) == 0
    assert "not enclosed" in capsys.readouterr().out


class TruthRenderer:
    """The mapper's `render_view` answered by the simulator's own camera: a map equal to the ground
    truth, alpha 1 where there is surface."""

    def __init__(self, camera) -> None:
        self.camera = camera

    def render_view(self, T_wc, K, width, height, outputs=("features", "alpha", "depth")):
        rgb, depth = self.camera.render(T_wc)
        t = lambda a: torch.from_numpy(np.asarray(a, np.float32)).reshape(1, height, width, -1)  # noqa: E731
        return RenderOutput(features=t(rgb), alpha=t(depth > 0), depth=t(depth))


def test_evaluation_of_a_holey_open_scan_keeps_views_that_see_surface(room_scan):
    path, _ = room_scan
    cfg = load_config("demo", TINY + [f"scene.path={path}", "evaluation.views=16"])
    rig = build_rig(cfg)
    ev = rig.evaluation_set()
    # looking up in a scan without a ceiling sees sky: such views are drawn again, else dropped and counted
    assert ev.dropped >= 1 and len(ev.poses) + ev.dropped == 16
    assert all(sees_surface(d[..., 0].numpy()) for d in ev.depth)
    first_draws = evaluation_poses(rig.scene, rig.start, rig.truth, rig.workspace, cfg)
    assert not all(sees_surface(rig.camera.render(T)[1]) for T in first_draws)  # the rule had work to do
    m = ev.evaluate(TruthRenderer(rig.camera))
    assert m["views"] == len(ev.poses) and m["views_dropped"] == ev.dropped
    numeric = {k: v for k, v in m.items() if isinstance(v, float)}
    assert all(math.isfinite(v) for v in numeric.values()), numeric
    # the ground truth as the map: zero error on every view, so every PSNR is the cap
    assert m["psnr"] == pytest.approx(60.0, abs=1e-4) and m["psnr_covered"] == pytest.approx(60.0, abs=1e-4)
    assert m["depth_l1_cm"] == pytest.approx(0.0, abs=1e-6) and m["covered_share"] >= VALID_DEPTH_SHARE


@pytest.mark.slow
def test_a_flight_in_a_holey_open_scan_reports_finite_metrics_and_dropped_views(room_scan, tmp_path, capsys):
    from flightrecon.experiments.run_eval import evaluate_run

    path, _ = room_scan
    run = tmp_path / "run"
    sets = TINY + [f"scene.path={path}", "evaluation.views=16", "budget.frames=4", "budget.initial_views=2",
                   "metrics.sample_points=20000"]
    assert cli_main(["fly", "demo", "--quiet", "--no-record", "--out", str(run),
                     *[a for s in sets for a in ("--set", s)]]) == 0
    summary = capsys.readouterr().out
    flown = json.loads((run / "metrics.json").read_text())["eval"]
    assert flown["views_dropped"] >= 1 and flown["views"] + flown["views_dropped"] == 16
    assert f"{flown['views']} evaluation views ({flown['views_dropped']} left out" in summary
    scored = evaluate_run(run)
    assert json.loads((run / "eval.json").read_text())["views_dropped"] == flown["views_dropped"]
    for key in ("psnr", "ssim", "depth_l1_cm", "accuracy_cm", "completion_cm", "chamfer_cm", "fscore"):
        assert math.isfinite(scored[key]), (key, scored[key])
