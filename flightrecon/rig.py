"""What a flight stands on, built in one place: the scene, its MuJoCo world and RGB-D camera, the
flight workspace, the take-off (checked safe: takeoff.py), the ground-truth distance field and the
evaluation views.

The closed loop (mission), the evaluation of finished runs and the survey all build it here, so a
change to how a scene is set up (a pad, the take-off rule) reaches every one of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flightrecon.config import ScenarioConfig
from flightrecon.evaluation.views import EvaluationSet
from flightrecon.scene.free_space import FreeSpace
from flightrecon.planning.distance_field import DistanceField
from flightrecon.planning.poses import start_position, workspace_of
from flightrecon.scene.source import scene_from_config
from flightrecon.scene.types import Scene
from flightrecon.sim.camera import RGBDCamera
from flightrecon.takeoff import TakeOff, safe_takeoff
from flightrecon.sim.world import World, build_world

TRUTH_PAD = 0.2  # m: the ground-truth field reaches this far beyond the workspace and the clearance


def takeoff_point(scene: Scene, cfg: ScenarioConfig) -> np.ndarray:
    """The hover point the drone takes off to: sim.takeoff_height above the scene's spawn (or its
    floor's center) when that is safe, else the nearest safe one (flightrecon.takeoff)."""
    return flight_region(scene, cfg)[1].hover


def flight_region(scene: Scene, cfg: ScenarioConfig) -> tuple[np.ndarray, TakeOff]:
    """(workspace box (2,3) for candidates, take-off): the planner's workspace of the scene, shrunk
    by the drone's required clearance, and the safe take-off, which starts from the hover point
    above its spawn when that one is safe."""
    pad = cfg.required_clearance
    room = workspace_of(scene, cfg.planner.max_height)
    work = room + np.array([[pad], [-pad]])
    return work, safe_takeoff(scene, cfg, start_position(scene, cfg.sim.takeoff_height), room, work)


def truth_field(scene: Scene, cfg: ScenarioConfig, workspace: np.ndarray) -> DistanceField:
    """Unsigned distance to the scene's mesh over the workspace and its margin (where the evaluation
    views may stand; flight clearance is measured exactly, by scene.surface_distance)."""
    pad = cfg.required_clearance + TRUTH_PAD
    return DistanceField.from_mesh(scene.trimesh, cfg.planner.voxel_size, workspace + np.array([[-pad], [pad]]),
                                   signed=False)


@dataclass
class Rig:
    """The scene set up for flying: what the loop, the evaluation and the survey share."""

    cfg: ScenarioConfig
    scene: Scene
    world: World
    camera: RGBDCamera
    workspace: np.ndarray  # (2,3): the box candidate viewpoints lie in
    takeoff: TakeOff  # where the drone rests, and the hover point it climbs to
    truth: DistanceField | None  # None when built with truth=False

    @property
    def K(self) -> np.ndarray:
        return self.camera.K

    @property
    def start(self) -> np.ndarray:
        """The take-off (hover) point."""
        return self.takeoff.hover

    @property
    def free(self) -> FreeSpace:
        """The room's free space: the empty voxels connected to the take-off point."""
        return self.takeoff.free

    def evaluation_set(self) -> EvaluationSet:
        """The scene's fixed evaluation views with their ground truth."""
        return EvaluationSet.for_mission(self.camera, self.start, self.truth, self.workspace, self.cfg, self.free)


def build_rig(cfg: ScenarioConfig, *, truth: bool = True) -> Rig:
    """Scene, world, camera, workspace, take-off and (unless truth=False) the truth field of `cfg`;
    SceneError when the scene holds no safe take-off for the drone."""
    c = cfg.camera
    scene = scene_from_config(cfg.scene)
    workspace, takeoff = flight_region(scene, cfg)  # before the world: a scene without room fails fast
    world = build_world(scene, cfg)
    camera = RGBDCamera(world, c.width, c.height, c.hfov_deg, c.near, c.far)
    return Rig(cfg, scene, world, camera, workspace, takeoff, truth_field(scene, cfg, workspace) if truth else None)
