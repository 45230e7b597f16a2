"""The files of a flight's run folder, named in one place: the loop writes them; resuming, the run
evaluation, the sweep, its report, the benchmarks and the viewer read them."""

from __future__ import annotations

from pathlib import Path

CONFIG = "config.toml"  # the resolved scenario of the run
PROVENANCE = "provenance.json"  # what each flight segment ran with (flightrecon.provenance)
CHECKPOINT = "checkpoint.npz"  # the loop's state after the last frame (flightrecon.checkpoint; resume)
LEGACY_CHECKPOINT = "checkpoint.pkl"  # the pickled checkpoint of earlier versions: refused, never read
FRAMES = "frames.csv"  # one row per frame: timings, counts, quality
PROFILE = "profile.csv"  # per frame, the loop's stage times and the mapping's own (flightrecon.flight_profile)
EVENTS = "events.log"
DIAGNOSIS = "diagnosis.csv"  # output.diagnose
MAP = "map.ply"  # the final map
TRAJECTORY = "trajectory.csv"  # the flown trajectory at the control rate
METRICS = "metrics.json"  # written last by the flight: its presence means the flight finished
RECORDING = "recording.rrd"  # the rerun timeline's first segment
SNAPSHOTS = "snapshots"  # map_<frame>.ply saved at each in-flight evaluation (evaluation.snapshots)
FAILED = "failed.txt"  # why the flight stopped (it diverged, touched the scene or met bad data); a sweep then skips it
EVAL = "eval.json"  # written last by `eval`: its presence means the run is scored
MESH = "mesh.ply"  # the TSDF mesh of the final map
DATASET = "dataset"  # output.dataset: the captured RGB-D frames and poses (transforms.json, flightrecon.dataset)
NOVEL_VIEW = "novel_view.npz"  # the first evaluation view's ground truth and renders
OVER_FRAMES = "eval_over_frames.csv"  # the snapshots' metrics over collected frames
LOCK = "flying.lock"  # held while a process flies the run (flightrecon.run_lock)


def scene_folder(scene: str, scene_seed: int | None) -> str:
    """The folder of a scene, or of one of its variants (scene.seed): each variant is a unit of its own."""
    return scene if scene_seed is None else f"{scene}.v{scene_seed}"


def base_scene(folder: str) -> str:
    """The scene a scene folder (or a variant's, `<scene>.v<K>`) belongs to."""
    head, sep, tail = folder.rpartition(".v")
    return head if sep and tail.isdigit() else folder


def snapshot_path(run_dir: str | Path, frame: int) -> Path:
    return Path(run_dir) / SNAPSHOTS / f"map_{frame:05d}.ply"


def snapshot_frame(path: str | Path) -> str:
    """The frame number (as written) of a snapshot file."""
    return Path(path).stem.split("_")[1]
