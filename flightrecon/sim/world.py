"""The MuJoCo world: a scene as visual-only textured mesh, collision boxes, lights, and the drone.

Assembled with MuJoCo's spec API. The scene's colors are baked into a texture atlas
(`scene.bake`) and its collision shape is a set of boxes following its surfaces
(`scene.collision`): a mesh geom would collide as its convex hull, i.e. a solid room. Both are
cached on disk keyed by the scene's content hash. The scene is drawn unlit: its material's
emission plus the headlight's ambient add to exactly 1, so rendered colors equal the mesh colors
(Replica renders are unlit too).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from flightrecon.fileio import atomic_path
from flightrecon.scene.bake import TextureAtlas, bake_atlas, scene_hash
from flightrecon.scene.collision import collision_boxes
from flightrecon.scene.source import cache_root
from flightrecon.scene.types import Scene

BAKE_VERSION = 4  # bump when baking changes, so cached assets are rebuilt
SCENE_MESH = "scene_mesh"
SCENE_GEOM = "scene_visual"
COLLISION_GROUP = 4  # hidden by MuJoCo's default visual options, like the drone's group 3
VISUAL_GROUP = 0
RENDER_CAMERA = "render_cam"
ATLAS_TEXTURE = "scene_atlas"


@dataclass(frozen=True)
class BakedScene:
    """What MuJoCo needs of a scene: its texture atlas and its collision boxes (center, half size)."""

    atlas: TextureAtlas
    boxes: np.ndarray  # (N, 6)
    collision_pitch: float  # voxel size the boxes were built at (may exceed the asked one)
    key: str
    from_cache: bool = False


@dataclass
class World:
    """A compiled world: model, data, the spec it came from, and the scene it shows."""

    model: mujoco.MjModel
    data: mujoco.MjData
    spec: mujoco.MjSpec
    scene: Scene
    baked: BakedScene
    collision_geom_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, int))

def bake_scene(scene: Scene, cache_dir: str = "", collision_voxel: float = 0.05) -> BakedScene:
    """Atlas + collision boxes for `scene`, from the cache when its content was baked before."""
    key = f"{scene_hash(scene)}-p{collision_voxel:g}-v{BAKE_VERSION}"
    path = cache_root(cache_dir) / "baked" / f"{key}.npz"
    if path.is_file():
        try:
            with np.load(path) as z:
                atlas = TextureAtlas(z["image"], z["texcoord"], z["face_texcoord"], int(z["max_mip_level"]))
                return BakedScene(atlas, z["boxes"], float(z["collision_pitch"]), key, from_cache=True)
        except (OSError, ValueError, KeyError):
            pass  # a damaged cache entry is rebuilt below
    boxes, pitch = collision_boxes(scene, collision_voxel)
    baked = BakedScene(bake_atlas(scene), boxes, pitch, key)
    try:
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, image=baked.atlas.image, texcoord=baked.atlas.texcoord,
                     face_texcoord=baked.atlas.face_texcoord, max_mip_level=baked.atlas.max_mip_level,
                     boxes=baked.boxes, collision_pitch=baked.collision_pitch)
    except OSError:
        pass  # a read-only cache only costs time
    return baked


def add_scene(spec: mujoco.MjSpec, scene: Scene, baked: BakedScene, ambient: float = 0.3) -> None:
    """Add the scene's textured visual mesh (no collisions, drawn from both sides) and its collision
    boxes (not drawn)."""
    atlas = baked.atlas
    h, w = atlas.image.shape[:2]
    tex = spec.add_texture(name=ATLAS_TEXTURE, type=mujoco.mjtTexture.mjTEXTURE_2D, width=w, height=h,
                           nchannel=3)
    tex.data = atlas.image.tobytes()
    mat = spec.add_material(name="scene_material", emission=1.0 - ambient, specular=0.0, shininess=0.0,
                            reflectance=0.0, rgba=[1, 1, 1, 1])
    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = ATLAS_TEXTURE
    mesh = spec.add_mesh(name=SCENE_MESH)
    mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
    mesh.maxhullvert = 4  # never collides: skip computing a useful hull
    mesh.uservert = np.asarray(scene.vertices, np.float32).ravel()
    # Every face both ways round: OpenGL culls a face seen from behind, and a scan's surfaces are
    # single sheets (a table top scanned from above, seen from below) that the collision boxes and the
    # true clearance hold either way; drawn one way only, the camera saw through what the drone hit.
    faces = np.asarray(scene.faces, np.int32)
    mesh.userface = np.concatenate([faces, faces[:, ::-1]]).ravel()
    mesh.usertexcoord = atlas.texcoord.ravel()
    corners = np.asarray(atlas.face_texcoord, np.int32)
    mesh.userfacetexcoord = np.concatenate([corners, corners[:, ::-1]]).ravel()
    spec.worldbody.add_geom(name=SCENE_GEOM, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=SCENE_MESH,
                            material="scene_material", contype=0, conaffinity=0, group=VISUAL_GROUP)
    for i, (cx, cy, cz, hx, hy, hz) in enumerate(baked.boxes):
        spec.worldbody.add_geom(name=f"scene_collision{i}", type=mujoco.mjtGeom.mjGEOM_BOX,
                                pos=[cx, cy, cz], size=[hx, hy, hz], contype=1, conaffinity=1,
                                group=COLLISION_GROUP, rgba=[0.9, 0.3, 0.3, 0.4])


def add_lights(spec: mujoco.MjSpec, ambient: float = 0.3) -> None:
    """Headlight ambient only: with the scene's emission it sums to 1, so the scene is unlit."""
    spec.visual.headlight.ambient = [ambient] * 3
    spec.visual.headlight.diffuse = [0.0] * 3
    spec.visual.headlight.specular = [0.0] * 3
    spec.visual.headlight.active = 1


def build_world(scene: Scene, cfg, with_drone: bool = True) -> World:
    """Compile the world for `scene` under the scenario config `cfg` (physics step, camera, drone)."""
    baked = bake_scene(scene, cfg.scene.cache_dir, cfg.scene.collision_voxel)
    spec = mujoco.MjSpec()
    spec.modelname = f"flightrecon_{scene.name}"
    spec.option.timestep = cfg.sim.physics_dt
    spec.visual.global_.offwidth = max(640, cfg.camera.width, cfg.selector.scoring_width)
    spec.visual.global_.offheight = max(480, cfg.camera.height, cfg.selector.scoring_height)
    spec.visual.quality.offsamples = 0  # no multisampling: each pixel is its center's color and depth
    add_lights(spec, cfg.scene.ambient)
    spec.worldbody.add_camera(name=RENDER_CAMERA)  # posed per frame by sim.camera.RGBDCamera.render
    add_scene(spec, scene, baked, cfg.scene.ambient)
    if with_drone:
        from flightrecon.sim.quadrotor import add_quadrotor

        add_quadrotor(spec, cfg)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    ids = np.array([model.geom(f"scene_collision{i}").id for i in range(len(baked.boxes))], int)
    return World(model, data, spec, scene, baked, ids)
