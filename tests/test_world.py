"""The MuJoCo world: scene collision follows real surfaces (not a hull), assets are cached, drone fits."""

from __future__ import annotations

import flightrecon  # noqa: F401  (selects EGL before mujoco loads)

import mujoco
import numpy as np
import pytest

from flightrecon.scenario import load_config
from flightrecon.scene.builder import QuadMeshBuilder
from flightrecon.scene.patterns import solid
from flightrecon.scene.procedural import make_scene
from flightrecon.scene.replica_ply import quads_to_triangles
from flightrecon.scene.types import Scene
from flightrecon.sim.world import SCENE_GEOM, add_scene, bake_scene, build_world

TABLE_H = 0.75


def _table_scene() -> Scene:
    """A floor (top at z = 0) and a 1.0 x 0.6 m table with 4 cm legs, top at TABLE_H."""
    rng = np.random.default_rng(0)
    b = QuadMeshBuilder()
    b.box([0, 0, -0.05], [4, 4, 0.1], solid([0.5, 0.5, 0.5], rng), 0.25)
    b.box([0, 0, TABLE_H - 0.015], [1.0, 0.6, 0.03], solid([0.6, 0.4, 0.2], rng), 0.1)
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.box([sx * 0.46, sy * 0.26, (TABLE_H - 0.03) / 2], [0.04, 0.04, TABLE_H - 0.03],
                  solid([0.2, 0.2, 0.2], rng), 0.1)
    v, c, n, q = b.build()
    return Scene("table", v.astype(np.float64), quads_to_triangles(q), vertex_colors=c, meta={"quad_faces": True})


def _cfg(tmp_path, *extra):
    return load_config(None, [f'scene.cache_dir="{tmp_path}"', *extra])


def test_spheres_rest_on_the_table_and_on_the_floor_beside_and_under_it(tmp_path):
    scene = _table_scene()
    pitch = 0.02
    baked = bake_scene(scene, str(tmp_path), pitch)
    spec = mujoco.MjSpec()
    spec.option.timestep = 0.002
    add_scene(spec, scene, baked)
    starts = {"on_table": [0.1, 0.05, 1.2], "beside": [0.8, 0.0, 1.2], "under": [0.0, 0.0, 0.4]}
    for name, pos in starts.items():
        body = spec.worldbody.add_body(name=name, pos=pos)
        body.add_freejoint()
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.05, 0, 0], mass=0.1)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data, nstep=1000)
    z = {name: data.body(name).xpos[2] for name in starts}
    r = 0.05
    # resting on the surface, at most the sample padding (a quarter voxel) above it: boxes hug the
    # samples they hold, so a physical surface stands where the camera sees it, not a voxel in front
    top = 0.25 * pitch + 0.003
    assert TABLE_H + r - 0.005 < z["on_table"] < TABLE_H + r + top
    assert r - 0.005 < z["beside"] < r + top  # a convex hull would hold it at table height
    assert r - 0.005 < z["under"] < r + top  # and would not let it fall between the legs
    assert model.geom(SCENE_GEOM).contype == 0 and model.geom(SCENE_GEOM).conaffinity == 0


@pytest.mark.slow
def test_collision_boxes_cover_the_surface_as_a_thin_shell(tmp_path):
    import trimesh

    scene = make_scene("room0")
    pitch = 0.05
    boxes = bake_scene(scene, str(tmp_path), pitch).boxes
    pts, _ = trimesh.sample.sample_surface(scene.trimesh, 20000, seed=1)
    lo, hi = boxes[:, :3] - boxes[:, 3:], boxes[:, :3] + boxes[:, 3:]
    covered = np.zeros(len(pts), bool)
    for s in range(0, len(pts), 2000):
        p = pts[s:s + 2000, None]
        covered[s:s + 2000] = np.any(np.all((p >= lo - 1e-9) & (p <= hi + 1e-9), axis=2), axis=1)
    assert covered.all()
    volume = np.prod(2 * boxes[:, 3:], axis=1).sum()
    assert volume < 2.0 * pitch * scene.trimesh.area  # a shell around the surface, not solid blocks
    free_lo, free_hi = np.asarray(scene.meta["free_box"])
    grid = np.stack(np.meshgrid(*[np.linspace(a, b, 5) for a, b in zip(free_lo, free_hi)]), -1).reshape(-1, 3)
    assert not np.all((grid[:, None] >= lo) & (grid[:, None] <= hi), axis=2).any()  # the room is empty


def test_collision_boxes_stand_a_quarter_voxel_in_front_of_an_off_grid_wall():
    from flightrecon.scene.collision import SAMPLE_SPACING, collision_boxes

    b = QuadMeshBuilder()
    b.box([0.537, 0.0, 1.0], [0.0, 2.0, 2.0], solid([0.5, 0.5, 0.5], np.random.default_rng(0)), 0.25)
    b.box([0.0, 0.0, -0.05], [2.0, 3.0, 0.1], solid([0.4, 0.4, 0.4], np.random.default_rng(1)), 0.25)
    v, c, n, q = b.build()
    scene = Scene("wall", v.astype(np.float64), quads_to_triangles(q), vertex_colors=c)
    pitch = 0.05
    boxes, _ = collision_boxes(scene, pitch)
    lo, hi = boxes[:, :3] - boxes[:, 3:], boxes[:, :3] + boxes[:, 3:]
    wall = (lo[:, 2] > 0.02) & (lo[:, 0] > 0.3)  # boxes above the floor's slab
    assert wall.any()
    pad = SAMPLE_SPACING * pitch
    # whole voxels would span 0.50..0.55 (+ pad): the surface a camera sees is at 0.537
    np.testing.assert_allclose(lo[wall, 0], 0.537 - pad, atol=1e-9)
    np.testing.assert_allclose(hi[wall, 0], 0.537 + pad, atol=1e-9)
    floor_top = hi[lo[:, 2] < -0.09, 2]  # the slab's top face at z = 0, in boxes of its own
    assert floor_top.size and floor_top.max() <= pad + 1e-9


def test_baked_assets_are_cached_by_content(tmp_path):
    scene = _table_scene()
    first = bake_scene(scene, str(tmp_path))
    second = bake_scene(scene, str(tmp_path))
    assert not first.from_cache and second.from_cache
    np.testing.assert_array_equal(first.atlas.image, second.atlas.image)
    np.testing.assert_array_equal(first.boxes, second.boxes)
    scene.vertex_colors[0] = 255 - scene.vertex_colors[0]  # different content, different key
    assert bake_scene(scene, str(tmp_path)).key != first.key
    cached = next((tmp_path / "baked").glob(f"{first.key}.npz"))
    cached.write_bytes(b"damaged")
    again = bake_scene(_table_scene(), str(tmp_path))
    assert not again.from_cache
    np.testing.assert_array_equal(again.atlas.image, first.atlas.image)


@pytest.mark.slow
def test_world_without_drone_exposes_model_data_spec_scene(tmp_path):
    scene = make_scene("room0")
    world = build_world(scene, _cfg(tmp_path), with_drone=False)
    m = world.model
    assert world.scene is scene and isinstance(world.spec, mujoco.MjSpec)
    assert m.nbody == 1 and m.nmeshvert == len(scene.vertices)
    assert m.nmeshface == 2 * len(scene.faces)  # every face drawn both ways round
    assert len(world.collision_geom_ids) == len(world.baked.boxes) > 0
    assert np.all(m.geom_contype[world.collision_geom_ids] == 1)
    h, w = world.baked.atlas.image.shape[:2]
    assert (m.tex_height[0], m.tex_width[0]) == (h, w)


@pytest.mark.slow
def test_drone_touching_a_wall_is_a_contact(tmp_path):
    pytest.importorskip("flightrecon.sim.quadrotor")
    from flightrecon.sim.quadrotor import DroneHandle

    scene = make_scene("room0")
    cfg = _cfg(tmp_path)
    world = build_world(scene, cfg, with_drone=True)
    m, d = world.model, world.data
    handle = DroneHandle(m)
    (x0, y0, z0), (x1, y1, z1) = scene.meta["room_box"]

    def contacts_at(p):
        d.qpos[handle.qpos_adr:handle.qpos_adr + 3] = p
        d.qpos[handle.qpos_adr + 3:handle.qpos_adr + 7] = [1, 0, 0, 0]
        mujoco.mj_forward(m, d)
        geoms = {int(g) for c in d.contact[:d.ncon] for g in (c.geom1, c.geom2)}
        return geoms & set(world.collision_geom_ids.tolist())

    assert not contacts_at([0.0, 0.0, 1.3])  # the free take-off column
    assert contacts_at([x1 - 0.5 * cfg.drone.body_radius, 0.3, 1.3])  # into the +x wall
    assert m.camera("drone_cam").id >= 0


def test_sloped_surface_coarsens_to_a_bounded_box_count_and_stays_covered():
    import trimesh

    from flightrecon.geometry import rot_x, rot_y
    from flightrecon.scene.collision import collision_boxes

    R = rot_x(0.4) @ rot_y(0.7)
    b = QuadMeshBuilder()
    b.plane([0, 0, 0], R @ [3.0, 0, 0], R @ [0, 3.0, 0], 0.25, solid([0.5, 0.5, 0.5], np.random.default_rng(0)))
    v, c, n, q = b.build()
    scene = Scene("slope", v.astype(np.float64), quads_to_triangles(q), vertex_colors=c)
    fine, fine_pitch = collision_boxes(scene, 0.05, max_boxes=100_000)
    boxes, pitch = collision_boxes(scene, 0.05, max_boxes=300)
    assert fine_pitch == 0.05 and len(fine) > 300
    assert len(boxes) <= 300 and pitch > 0.05
    pts, _ = trimesh.sample.sample_surface(scene.trimesh, 5000, seed=2)
    lo, hi = boxes[:, :3] - boxes[:, 3:], boxes[:, :3] + boxes[:, 3:]
    inside = np.all((pts[:, None] >= lo - 1e-9) & (pts[:, None] <= hi + 1e-9), axis=2).any(axis=1)
    assert inside.all()
