"""The scene a scenario asks for: a user's mesh file, or a procedural scene cached on disk.

Procedural scenes are written once in Replica's format under the cache folder and read back
through the same loader real data uses; baked MuJoCo assets live in the same cache.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from flightrecon.fileio import write_text
from flightrecon.scene.loaders import META_FILE, load_scene
from flightrecon.scene.procedural import GENERATOR_VERSION, make_scene
from flightrecon.scene.replica_ply import write_replica_ply
from flightrecon.scene.types import Scene


def cache_root(cache_dir: str = "") -> Path:
    """The cache folder: the config's `scene.cache_dir`, else $XDG_CACHE_HOME or ~/.cache, /flightrecon."""
    if cache_dir:
        return Path(cache_dir).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "flightrecon"


def write_scene_dir(scene: Scene, out_dir: str | os.PathLike) -> Path:
    """Write `scene` as out_dir/mesh.ply plus its metadata sidecar; returns the mesh path."""
    out = Path(out_dir)
    mesh = write_replica_ply(scene, out / "mesh.ply")
    write_text(out / META_FILE, json.dumps({"mesh": mesh.name, "name": scene.name, **scene.meta},
                                           indent=1, sort_keys=True) + "\n")
    return mesh


def procedural_scene(name: str, seed: int = 0, cache_dir: str = "") -> Scene:
    """The named procedural scene, generated on first use and then loaded from the cache."""
    folder = cache_root(cache_dir) / "scenes" / f"{name}-seed{seed}-v{GENERATOR_VERSION}"
    if (folder / "mesh.ply").is_file() and (folder / META_FILE).is_file():
        return load_scene(folder / "mesh.ply", name=name)
    scene = make_scene(name, seed)
    scene.source = write_scene_dir(scene, folder)
    return scene


def scene_from_config(cfg) -> Scene:
    """`cfg` is a config.SceneConfig: `path` set -> that file; otherwise the procedural `name`."""
    if cfg.path:
        return load_scene(cfg.path, unit_scale=cfg.unit_scale, up_axis=cfg.up_axis, name=cfg.name or None,
                          up_vector=cfg.up_vector, rotation_deg=cfg.rotation_deg)
    return procedural_scene(cfg.name, cfg.seed, cfg.cache_dir)
