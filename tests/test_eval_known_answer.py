"""The evaluation pipeline end to end on known answers: the ground-truth mesh itself, rendered as the
"map" (by ray casting, independent of the simulator's renderer), scores F-score ~1, accuracy and
completion ~0 and depth L1 ~0 against the simulator's ground truth; a copy shifted by 2 cm along x
scores the accuracy that shift implies (2 cm on the x-facing share of the visible surface), and
one shifted by 8 cm loses exactly that share from precision and recall at the 5 cm threshold."""

import numpy as np
import pytest
import torch
import trimesh

from flightrecon.experiments.run_eval import evaluation_truth_for
from flightrecon.evaluation.map_metrics import evaluate_map
from flightrecon.render import RenderOutput
from flightrecon.scenario import load_config

ROOM = (4.0, 3.0, 2.5)
CUBE, CUBE_AT = 0.6, (0.8, 0.5)


def _room() -> trimesh.Trimesh:
    """A closed box room (inner faces looking in, outer faces out) with a cube on its floor, floor at z = 0."""
    inner = trimesh.creation.box(extents=ROOM)
    inner.invert()
    outer = trimesh.creation.box(extents=(4.4, 3.4, 2.9))
    cube = trimesh.creation.box(extents=(CUBE,) * 3)
    cube.apply_translation((*CUBE_AT, -ROOM[2] / 2 + CUBE / 2))
    mesh = trimesh.util.concatenate([inner, outer, cube])
    mesh.apply_translation((0.0, 0.0, ROOM[2] / 2))
    mesh.visual.vertex_colors = np.tile([180, 160, 140, 255], (len(mesh.vertices), 1))
    return mesh


class RayCastRenderer:
    """The mapper's `render_view` for a mesh: z-depth, alpha 1 where a ray hits, camera-facing normals."""

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        self.mesh = mesh
        self.rays = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)

    def render_view(self, T_wc, K, width, height, outputs=("features", "alpha", "depth")):
        u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
        dirs_c = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(-1, 3)
        dirs = dirs_c @ T_wc[:3, :3].T
        origins = np.repeat(T_wc[:3, 3][None], len(dirs), 0)
        loc, ray, tri = self.rays.intersects_location(origins, dirs, multiple_hits=False)
        depth = np.zeros(len(dirs))
        depth[ray] = (loc - T_wc[:3, 3]) @ T_wc[:3, 2]  # z-depth: along the optical axis
        normal = np.zeros((len(dirs), 3))
        n_c = self.mesh.face_normals[tri] @ T_wc[:3, :3]
        normal[ray] = n_c * -np.sign((n_c * dirs_c[ray]).sum(-1, keepdims=True))
        t = lambda a, k: torch.as_tensor(a.reshape(1, height, width, k), dtype=torch.float32)  # noqa: E731
        hit = (depth > 0).astype(float)
        return RenderOutput(features=t(np.repeat(hit[:, None], 3, 1) * 0.6, 3), alpha=t(hit, 1), depth=t(depth, 1),
                            normal=t(normal, 3))


@pytest.fixture(scope="module")
def scored(tmp_path_factory):
    path = tmp_path_factory.mktemp("room") / "mesh.ply"
    mesh = _room()
    mesh.export(path)
    cfg = load_config("demo", [f"scene.path={path}", "camera.width=64", "camera.height=48", "evaluation.views=8",
                               "metrics.tsdf_voxel=0.02", "metrics.tsdf_truncation=0.06",
                               "metrics.sample_points=60000"])
    truth = evaluation_truth_for(cfg)
    out = {}
    for shift in (0.0, 0.02, 0.08):
        moved = mesh.copy()
        moved.apply_translation((shift, 0.0, 0.0))
        metrics, _, recon = evaluate_map(RayCastRenderer(moved), cfg, truth, None)
        out[shift] = metrics
        out[f"mesh{shift}"] = recon
        out["count"] = cfg.metrics.sample_points
    visible = 2 * (ROOM[0] * ROOM[1] + ROOM[0] * ROOM[2] + ROOM[1] * ROOM[2]) - CUBE ** 2 + 4 * CUBE ** 2
    x_facing = 2 * ROOM[1] * ROOM[2] + 2 * CUBE ** 2
    return out, x_facing / visible


def test_the_ground_truth_as_the_map_scores_perfect(scored):
    m = scored[0][0.0]
    assert m["fscore"] > 0.99 and m["precision"] > 0.99 and m["recall"] > 0.99
    # what remains is the TSDF fusion's own error at 2 cm voxels from 48 px fusion views
    assert m["accuracy_cm"] < 1.0 and m["completion_cm"] < 1.0
    assert m["depth_l1_cm"] < 0.5  # ray-cast depth against the simulator's rendered ground truth
    assert m["covered_share"] > 0.99 and np.isfinite(m["psnr"])


def _box_surface_distance(p: np.ndarray, center, half) -> np.ndarray:
    """Exact distance from points to the surface of an axis-aligned box."""
    q = np.abs(p - np.asarray(center)) - np.asarray(half)
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    return np.where((q > 0).any(1), outside, -q.max(1))


def _room_distance(p: np.ndarray) -> np.ndarray:
    """Exact distance from points to the room's triangles: inner and outer walls and the cube."""
    mid = (0.0, 0.0, ROOM[2] / 2)
    return np.minimum.reduce([_box_surface_distance(p, mid, np.array(ROOM) / 2),
                              _box_surface_distance(p, mid, np.array((4.4, 3.4, 2.9)) / 2),
                              _box_surface_distance(p, (*CUBE_AT, CUBE / 2), (CUBE / 2,) * 3)])


def test_a_2cm_shift_scores_the_accuracy_it_implies(scored):
    """Accuracy is the mean exact distance of the reconstruction's samples to the room (the box
    geometry written out); on the x-facing walls that distance is the 2 cm shift, up to the TSDF's
    own error, and elsewhere the shift slides surfaces along themselves and adds nothing."""
    from flightrecon.evaluation.mesh_metrics import sample_surface

    out, share = scored
    for shift in (0.0, 0.02):
        recon = out[f"mesh{shift}"]
        pts = sample_surface(np.asarray(recon.vertices), np.asarray(recon.faces), out["count"], seed=0)
        d = _room_distance(pts)
        assert out[shift]["accuracy_cm"] == pytest.approx(100 * d.mean(), abs=0.01)
        on_x_walls = np.abs(np.abs(pts[:, 0] - shift) - ROOM[0] / 2) < 0.03
        assert on_x_walls.mean() == pytest.approx(share, abs=0.03)
        if shift:
            assert 100 * d[on_x_walls].mean() == pytest.approx(2.0, abs=0.3)
            assert 100 * d[~on_x_walls].mean() < out[0.0]["accuracy_cm"] + 0.3
    assert out[0.02]["fscore"] > 0.99  # every point is still within 5 cm


def test_an_8cm_shift_loses_the_x_facing_share_at_the_5cm_threshold(scored):
    out, share = scored
    assert out[0.08]["precision"] == pytest.approx(1 - share, abs=0.03)
    assert out[0.08]["recall"] == pytest.approx(1 - share, abs=0.03)
    assert out[0.08]["accuracy_cm"] == pytest.approx(out[0.0]["accuracy_cm"] + 8.0 * share, abs=0.4)
