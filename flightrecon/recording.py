"""Rerun timeline of a flight: researchers review flights in rerun.

`open_recorder(cfg, run_dir, stage, ...)` returns a `Recorder` that the closed loop calls at fixed
points (capture, candidates, flight, events, end of frame) with what that step produced; with
recording off it returns `NullRecorder`, whose hooks do nothing, so `--no-record` costs one empty
method call per hook. The recorder only reads what it is handed (it renders nothing and draws no
random numbers), so a flight is the same with and without it.

Timelines: `frame` (capture index) and `sim_time` (simulated seconds). Entities:
  world/scene                     decimated ground-truth mesh (static)
  world/drone, world/drone/body   body pose at `record_pose_rate_hz` of sim time; arms, rotors (static)
  world/camera                    estimated camera pose at each capture, pinhole (OpenCV axes),
  world/camera/image, /depth      captured color (JPEG) and depth (16-bit PNG, millimeters)
  rendered/color|depth|normal     the map rendered at the capture pose, after mapping the frame
  world/map/splats                splats as flat ellipsoids (1 sigma) in their color, every
                                  `record_map_every` frames, at most `record_map_max_splats` of them
  world/map/reliability           the same splats as points colored by front-side reliability
                                  (red 0 -> green 1); hidden in the default layout
  world/candidates/{feasible,infeasible,chosen}  arrows; feasible colored by score (blue low ->
                                  yellow high), infeasible gray by reason (a class per reason),
                                  chosen magenta with its score as label
  world/plan/chosen, world/plan/feasible  planned trajectories (chosen, and every feasible one)
  world/flown, world/flown/samples  flown path of each flight (accumulating in the default layout),
                                  samples red where clearance < body radius + safety margin
  plots/...                       frame PSNR and depth L1, splats, scoring time, chosen MI,
                                  feasible count, clearance, evaluation PSNR
  events                          the mission's event log (recoveries, contacts, flightrecon warnings)
                                  and, at debug level, each step's candidate summary by reason

Live (`fly --rerun`): a native viewer is spawned when there is a display; headless, rerun's web
viewer is served and its address printed (it stops with the flight).

Files: the first session writes `recording.rrd`; every `--resume` writes the next segment
`recording.resume<k>.rrd` with the same recording id, so the viewer merges the segments into one
recording when they are opened together (`flightrecon view RUN_DIR` opens them all). Frames after
the last checkpoint of a killed session are recorded again by the resume (same frame index).

Size (measured at 320x240): ~0.11 MB per frame of images and candidates, ~60 bytes per logged splat
per map snapshot, ~1.4 MB of scene mesh once.
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import rerun as rr
import rerun.blueprint as rrb
import torch

from flightrecon import run_folder
from flightrecon.config import ScenarioConfig
from flightrecon.metric_defs import METRICS
from flightrecon.scene.types import Scene

APP_ID = "flightrecon"
FIRST_SEGMENT = run_folder.RECORDING
log = logging.getLogger(__name__)


def recording_segments(run_dir: str | Path) -> list[Path]:
    """The run's recording files in session order (first flight, then each resume)."""
    run_dir = Path(run_dir)
    first = run_dir / FIRST_SEGMENT
    resumes = sorted(run_dir.glob("recording.resume*.rrd"), key=lambda p: int(p.stem.rsplit("resume", 1)[1] or 0))
    return ([first] if first.is_file() else []) + resumes


def _next_segment(run_dir: Path) -> Path:
    done = recording_segments(run_dir)
    return run_dir / (FIRST_SEGMENT if not done else f"recording.resume{len(done)}.rrd")


def recording_id(run_dir: Path) -> str:
    """One id per run folder, so resumed segments merge with the first in the viewer."""
    return "run-" + hashlib.sha1(str(Path(run_dir).resolve()).encode()).hexdigest()[:16]


def has_display() -> bool:
    """Whether a native viewer window can open (Linux needs an X11 or Wayland display)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


@dataclass(frozen=True)
class Stage:
    """The static part of the recording: the scene, the workspace box (2,3) and the camera K."""

    scene: Scene
    workspace: np.ndarray
    K: np.ndarray


class NullRecorder:
    """Recording off: every hook of `Recorder` does nothing."""

    def capture(self, frame: int, sim_time: float, obs, gmap, last: bool) -> None:
        pass

    def candidates(self, results, feasible, scores, chosen) -> None:
        pass

    def flight(self, flown, chosen=None) -> None:
        pass

    def event(self, text: str) -> None:
        pass

    def frame_done(self, row: dict) -> None:
        pass

    def close(self) -> None:
        pass


def open_recorder(cfg: ScenarioConfig, run_dir: Path, stage: Stage | None = None, *, frame: int = 0,
                  sim_time: float = 0.0, takeoff: dict | None = None,
                  live: bool = False) -> "Recorder | NullRecorder":
    """The recorder of a flight in `run_dir` starting at `frame` and `sim_time` (the take-off's
    flight-log columns when it starts at the beginning): a file segment (output.record) and/or a
    live viewer. `stage` is needed only when something is recorded."""
    out = cfg.output
    if not out.record and not live:
        return NullRecorder()
    run_dir = Path(run_dir)
    stream = rr.RecordingStream(APP_ID, recording_id=recording_id(run_dir))
    sinks = []
    if out.record:
        run_dir.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(_next_segment(run_dir))))
    if live:
        sinks.append(_live_sink(out.viewer_port, out.web_port, run_dir))
    stream.set_sinks(*sinks)
    return Recorder(cfg, stage, stream, frame, sim_time, takeoff)


def _live_sink(grpc_port: int, web_port: int, run_dir: Path):
    """A native viewer when there is a display, else the web viewer (address printed)."""
    if has_display():
        rr.spawn(port=grpc_port, connect=False)
        return rr.GrpcSink(f"rerun+http://127.0.0.1:{grpc_port}/proxy")
    sink = rr.GrpcServerSink(port=grpc_port)
    rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=sink.uri)
    print(f"no display: live web viewer at {web_viewer_address(web_port, grpc_port)} "
          f"(it stops when the flight ends; `flightrecon view {run_dir} --web` replays the run)", flush=True)
    return sink


def web_viewer_address(web_port: int, grpc_port: int, host: str = "127.0.0.1") -> str:
    return f"http://{host}:{web_port}/?url=rerun%2Bhttp%3A%2F%2F{host}%3A{grpc_port}%2Fproxy"


class Recorder:
    """Logs one flight to a rerun stream; the hooks mirror the loop's steps and receive what each
    step produced."""

    def __init__(self, cfg: ScenarioConfig, stage: Stage, stream: rr.RecordingStream, frame: int,
                 sim_time: float, takeoff: dict | None) -> None:
        self.cfg = cfg
        self.rec = stream
        self.out = cfg.output
        self.reasons: dict[str, int] = {}
        self.frame = frame
        self.capture_time = sim_time
        self._handler = _WarningsToEvents(self)
        logging.getLogger("flightrecon").addHandler(self._handler)
        self.rec.send_blueprint(default_blueprint(stage.workspace))
        self._static(stage)
        if takeoff is not None and len(takeoff["t"]):
            self._poses(takeoff, 0)
        self._at_frame()
        self.rec.log("events", rr.TextLog(f"recording from frame {frame} at sim time {sim_time:.2f} s",
                                          level=rr.TextLogLevel.INFO))

    # ---------------------------------------------------------------- static scene
    def _static(self, stage: Stage) -> None:
        rec = self.rec
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        v, f, c = decimate_mesh(stage.scene, self.out.record_mesh_cell)
        rec.log("world/scene", rr.Mesh3D(vertex_positions=v, triangle_indices=f, vertex_colors=c), static=True)
        lo, hi = stage.workspace
        rec.log("world/workspace", rr.Boxes3D(mins=[lo], sizes=[hi - lo], colors=[(120, 120, 120)]), static=True)
        arm = self.cfg.drone.arm_length
        tips = arm / math.sqrt(2) * np.array([[1, 1, 0], [-1, -1, 0], [1, -1, 0], [-1, 1, 0]], np.float32)
        rec.log("world/drone/body", rr.LineStrips3D([tips[:2], tips[2:]], radii=0.01, colors=[(30, 30, 30)]),
                static=True)
        rec.log("world/drone/rotors", rr.Cylinders3D(lengths=[0.02] * 4, radii=[0.35 * arm] * 4, centers=tips,
                                                     colors=[(220, 60, 60), (220, 60, 60), (60, 60, 220),
                                                             (60, 60, 220)]), static=True)
        c = self.cfg.camera
        rec.log("world/camera", rr.Pinhole(image_from_camera=stage.K, width=c.width, height=c.height,
                                           camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.3),
                static=True)

    # ---------------------------------------------------------------- hooks
    def _at_frame(self, sim_time: float | None = None) -> None:
        self.rec.set_time("frame", sequence=self.frame)
        self.rec.set_time("sim_time", duration=self.capture_time if sim_time is None else sim_time)

    def capture(self, frame: int, sim_time: float, obs, gmap, last: bool) -> None:
        """Capture `frame` at `sim_time`: its images and pose, the map rendered at the pose (obs.view),
        and every record_map_every frames and at the `last` the map `gmap` (a GaussianMap)."""
        rec = self.rec
        self.frame, self.capture_time = frame, sim_time
        self._at_frame()
        rec.log("world/camera", rr.Transform3D(translation=obs.T_wc[:3, 3], mat3x3=obs.T_wc[:3, :3]))
        q = self.out.record_jpeg_quality
        rec.log("world/camera/image", rr.Image(_to_u8(obs.rgb)).compress(jpeg_quality=q))
        rec.log("world/camera/depth", _depth_png(obs.depth))
        r = obs.view.output  # the loop's render of the map at this pose
        color, depth, normal = (t[0].detach().cpu().numpy() for t in (r.features, r.depth, r.normal))
        rec.log("rendered/color", rr.Image(_to_u8(color.clip(0, 1))).compress(jpeg_quality=q))
        rec.log("rendered/depth", _depth_png(depth[..., 0]))
        rec.log("rendered/normal", rr.Image(_to_u8(0.5 + 0.5 * normal)).compress(jpeg_quality=q))
        if frame % self.out.record_map_every == 0 or last:
            self._map(gmap)

    def _map(self, g) -> None:
        n = len(g)
        if n == 0:
            return
        keep = np.arange(n)
        if n > self.out.record_map_max_splats:  # a fixed stride: deterministic and spread over the map
            keep = np.linspace(0, n - 1, self.out.record_map_max_splats).astype(np.int64)
        idx = torch.as_tensor(keep)
        with torch.no_grad():
            means = g["means"][idx].cpu().numpy()
            quats = torch.nn.functional.normalize(g["quats"][idx], dim=-1).cpu().numpy()
            scales = torch.exp(g["log_scales"][idx]).cpu().numpy()
            colors = g["colors"][idx].clamp(0, 1).cpu().numpy()
            front = torch.sigmoid(g["reliability"][idx, 0]).cpu().numpy() if "reliability" in g else None
        half = np.concatenate([scales, np.full((len(keep), 1), 1e-3, np.float32)], 1)
        self.rec.log("world/map/splats", rr.Ellipsoids3D(
            centers=means, half_sizes=half, quaternions=quats[:, [1, 2, 3, 0]], colors=_to_u8(colors),
            fill_mode=rr.components.FillMode.Solid))
        if front is not None:  # 2D GauSS-MI's column (the selectors that keep it)
            rel = np.stack([1.0 - front, front, np.zeros_like(front)], 1)
            self.rec.log("world/map/reliability", rr.Points3D(means, colors=_to_u8(rel), radii=0.01))

    def candidates(self, results, feasible, scores, chosen) -> None:
        """Every candidate of this step: scored, infeasible (by reason), and the chosen one."""
        self._at_frame()
        rec = self.rec
        bad = [r for r in results if not r.feasible]
        counts: dict[str, int] = {}
        for r in bad:
            counts[r.reason] = counts.get(r.reason, 0) + 1
        rec.log("events", rr.TextLog(f"frame {self.frame}: {len(feasible)} of {len(results)} candidates "
                                     f"feasible; infeasible by reason {counts}", level=rr.TextLogLevel.DEBUG))
        if bad:
            new = sorted({r.reason for r in bad} - set(self.reasons))
            for reason in new:
                self.reasons[reason] = len(self.reasons) + 1
            if new:
                rec.log("world/candidates/infeasible", rr.AnnotationContext(
                    [(k, reason, _gray(k)) for reason, k in self.reasons.items()]), static=True)
            rec.log("world/candidates/infeasible", rr.Arrows3D(
                origins=[r.position for r in bad], vectors=_headings([r.yaw for r in bad], 0.2), radii=0.006,
                class_ids=[self.reasons[r.reason] for r in bad]))
        else:
            rec.log("world/candidates/infeasible", rr.Clear(recursive=False))
        if feasible:
            s = np.zeros(len(feasible)) if scores is None else np.asarray(scores, float)
            rec.log("world/candidates/feasible", rr.Arrows3D(
                origins=[r.position for r in feasible], vectors=_headings([r.yaw for r in feasible], 0.3),
                radii=0.01, colors=_score_colors(s), labels=[f"{x:.4g}" for x in s], show_labels=False))
            rec.log("world/plan/feasible", rr.LineStrips3D([_path(r.trajectory, 12) for r in feasible],
                                                           radii=0.003, colors=[(90, 140, 220)]))
        else:
            rec.log("world/candidates/feasible", rr.Clear(recursive=False))
            rec.log("world/plan/feasible", rr.Clear(recursive=False))
        if chosen is not None:
            at = [i for i, r in enumerate(feasible) if r is chosen]
            label = "chosen" if scores is None or not at else f"chosen {float(np.asarray(scores)[at[0]]):.4g}"
            rec.log("world/candidates/chosen", rr.Arrows3D(
                origins=[chosen.position], vectors=_headings([chosen.yaw], 0.45), radii=0.025,
                colors=[(230, 0, 230)], labels=[label], show_labels=True))
            rec.log("world/plan/chosen", rr.LineStrips3D([_path(chosen.trajectory, 50)], radii=0.012,
                                                         colors=[(230, 0, 230)]))
        else:
            rec.log("world/candidates/chosen", rr.Clear(recursive=False))
            rec.log("world/plan/chosen", rr.Clear(recursive=False))

    def flight(self, flown, chosen=None) -> None:
        """The flown segment (of `chosen`, None: take-off or hover): body pose and clearance over sim
        time, and the path at this frame, red where clearance fell below body radius + safety margin."""
        if not len(flown):
            return
        cols = flown.columns()
        path, clear = self._poses(cols, self.frame + 1)
        self._at_frame()
        near = np.nan_to_num(clear, nan=np.inf) < self.cfg.required_clearance
        colors = np.where(near[:, None], np.array([230, 60, 40]), np.array([40, 180, 60])).astype(np.uint8)
        flown_s = float(cols["t"][-1] - cols["t"][0])
        label = f"flown {flown_s:.1f} s" + ("" if chosen is None else f" (planned {chosen.duration:.1f} s)")
        # the label shows on hover/selection only: drawn, the accumulating labels would cover the path
        self.rec.log("world/flown", rr.LineStrips3D([path], radii=0.015, colors=[(40, 180, 60)], labels=[label],
                                                    show_labels=False))
        self.rec.log("world/flown/samples", rr.Points3D(path, radii=0.022, colors=colors))

    def _poses(self, cols: dict, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """Body pose and clearance at `record_pose_rate_hz` of sim time; on the frame timeline they
        belong to `frame`, the capture the flight leads to, so frame k shows the drone at capture k."""
        n = len(cols["t"])
        step = max(1, int(round(self.cfg.sim.control_rate_hz / self.out.record_pose_rate_hz)))
        sel = np.unique(np.r_[np.arange(0, n, step), n - 1])
        pos = np.stack([cols["x"], cols["y"], cols["z"]], 1)[sel]
        quat = np.stack([cols["qx"], cols["qy"], cols["qz"], cols["qw"]], 1)[sel]
        clear = cols["clearance"][sel]
        times = [rr.TimeColumn("sim_time", duration=cols["t"][sel]),
                 rr.TimeColumn("frame", sequence=np.full(len(sel), frame))]
        self.rec.send_columns("world/drone", indexes=times,
                              columns=rr.Transform3D.columns(translation=pos, quaternion=quat))
        if np.isfinite(clear).any():
            self.rec.send_columns("plots/clearance", indexes=times, columns=rr.Scalars.columns(scalars=clear))
        return pos, clear

    def event(self, text: str) -> None:
        self._at_frame()
        level = rr.TextLogLevel.WARN if ("contact" in text or "no feasible" in text or "did not" in text) \
            else rr.TextLogLevel.INFO
        self.rec.log("events", rr.TextLog(text, level=level))

    def frame_done(self, row: dict) -> None:
        """The frame's scalars, at its capture time."""
        self._at_frame(row.get("sim_time"))
        for key in ("frame_psnr", "frame_depth_l1_cm", "n_splats", "t_score", "chosen_score", "n_feasible",
                    "eval_psnr", "eval_depth_l1_cm"):
            v = row.get(key)
            if v is not None and np.isfinite(float(v)):
                self.rec.log(f"plots/{key}", rr.Scalars(float(v)))

    def close(self) -> None:
        logging.getLogger("flightrecon").removeHandler(self._handler)
        self.rec.flush()
        self.rec.disconnect()


class _WarningsToEvents(logging.Handler):
    """flightrecon warnings from any module land in the event log too."""

    def __init__(self, recorder: Recorder) -> None:
        super().__init__(logging.WARNING)
        self.recorder = recorder

    def emit(self, record: logging.LogRecord) -> None:
        self.recorder._at_frame()
        self.recorder.rec.log("events", rr.TextLog(f"{record.name}: {record.getMessage()}",
                                                   level=rr.TextLogLevel.WARN))


def default_blueprint(workspace: np.ndarray | None = None) -> rrb.Blueprint:
    """3D view on the left; camera and rendered images, plots and the event log on the right.

    The flown path accumulates (every past frame up to the time cursor, on either timeline);
    everything else shows the latest state. The reliability-colored map is in the view but hidden:
    toggle its eye in the blueprint panel (and hide world/map/splats) to switch coloring.
    With the flight `workspace` (2, 3) the 3D view's eye starts inside it, at an upper corner looking
    at the floor's center: rerun's default eye looks at the scene's bounds from outside, so a
    closed room's walls and ceiling hide the flight."""
    past = rrb.VisibleTimeRanges([
        rrb.VisibleTimeRange(tl, start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.cursor_relative())
        for tl in ("frame", "sim_time")])
    view3d = rrb.Spatial3DView(
        origin="world", name="flight",
        overrides={"world/flown": past, "world/flown/samples": past,
                   "world/map/reliability": rrb.EntityBehavior(visible=False)},
        eye_controls=None if workspace is None else rrb.EyeControls3D(
            position=np.asarray(workspace[1], float), eye_up=[0.0, 0.0, 1.0],
            look_target=[*np.mean(workspace, 0)[:2], float(workspace[0][2])]))
    images = rrb.Grid(
        rrb.Spatial2DView(origin="world/camera", contents=["+ $origin/image"], name="captured color"),
        rrb.Spatial2DView(origin="world/camera", contents=["+ $origin/depth"], name="captured depth"),
        rrb.Spatial2DView(origin="rendered/color", name="rendered color"),
        rrb.Spatial2DView(origin="rendered/depth", name="rendered depth"),
        rrb.Spatial2DView(origin="rendered/normal", name="rendered normal"),
        grid_columns=3)
    plots = rrb.Tabs(
        rrb.TimeSeriesView(origin="plots", contents=["+ $origin/frame_psnr", "+ $origin/eval_psnr"],
                           name=METRICS["psnr"].heading),
        rrb.TimeSeriesView(origin="plots", contents=["+ $origin/frame_depth_l1_cm", "+ $origin/eval_depth_l1_cm"],
                           name=METRICS["depth_l1_cm"].heading),
        rrb.TimeSeriesView(origin="plots", contents=["+ $origin/n_splats"], name="splats"),
        rrb.TimeSeriesView(origin="plots", contents=["+ $origin/chosen_score"], name="chosen MI"),
        rrb.TimeSeriesView(origin="plots", contents=["+ $origin/t_score", "+ $origin/n_feasible"],
                           name="candidates"),
        rrb.TimeSeriesView(origin="plots", contents=["+ $origin/clearance"], name="clearance (m)"),
    )
    return rrb.Blueprint(
        rrb.Horizontal(view3d, rrb.Vertical(images, plots, rrb.TextLogView(origin="events", name="events"),
                                            row_shares=[3, 2, 1]), column_shares=[3, 2]),
        rrb.TimePanel(state="expanded", timeline="frame"),
        collapse_panels=False)


# -------------------------------------------------------------------- small conversions
def decimate_mesh(scene, cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Vertex clustering on a `cell`-meter grid: vertices in one cell merge (mean position and color),
    collapsed and duplicate triangles are dropped. Keeps the room's shape at a fraction of the size."""
    v = np.asarray(scene.vertices, np.float64)
    keys = np.floor((v - v.min(0)) / cell).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    verts = np.zeros((len(counts), 3))
    np.add.at(verts, inverse, v)
    verts /= counts[:, None]
    colors = None
    if scene.vertex_colors is not None:
        colors = np.zeros((len(counts), 3))
        np.add.at(colors, inverse, np.asarray(scene.vertex_colors, np.float64)[:, :3])
        colors = (colors / counts[:, None]).astype(np.uint8)
    f = inverse[np.asarray(scene.faces)]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    f = np.unique(f, axis=0)
    return verts.astype(np.float32), f.astype(np.uint32), colors


def _to_u8(x: np.ndarray) -> np.ndarray:
    return (np.clip(np.asarray(x, np.float32), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _depth_png(depth: np.ndarray) -> rr.EncodedDepthImage:
    """Depth in meters -> lossless 16-bit PNG in millimeters (0 stays invalid)."""
    mm = np.clip(np.nan_to_num(np.asarray(depth, np.float32)) * 1000.0 + 0.5, 0, 65535).astype(np.uint16)
    ok, png = cv2.imencode(".png", mm)
    if not ok:
        raise RuntimeError("cv2 could not encode a depth PNG")
    return rr.EncodedDepthImage(png.tobytes(), media_type="image/png", meter=1000.0)


def _headings(yaws, length: float) -> np.ndarray:
    y = np.asarray(yaws, float)
    return length * np.stack([np.cos(y), np.sin(y), np.zeros_like(y)], 1)


def _path(traj, n: int) -> np.ndarray:
    p = traj.evaluate(np.linspace(0.0, traj.duration, n))[0]
    return p[:, :3]


def _score_colors(s: np.ndarray) -> np.ndarray:
    """Blue (lowest score of the step) to yellow (highest)."""
    span = float(s.max() - s.min()) if len(s) else 0.0
    u = (s - s.min()) / span if span > 0 else np.ones_like(s)
    lo, hi = np.array([40, 60, 200]), np.array([250, 220, 30])
    return (lo + u[:, None] * (hi - lo)).astype(np.uint8)


def _gray(k: int) -> tuple[int, int, int]:
    g = 90 + (37 * k) % 120
    return (g, g, g)
