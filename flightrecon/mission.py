"""The closed loop of active reconstruction (docs/architecture.md, "One active step").

Each step: the drone has settled at a viewpoint and captures RGB-D at its actual simulated pose;
the mapper adds and optimizes splats; the selector updates its state (reliability for 2D
GauSS-MI); the occupancy map takes the depth; the planner checks the candidate library around the
drone; the selector scores the feasible candidates; the controller flies the best one's trajectory
in the fixed-rate cycle until arrival. The first `budget.initial_views` frames turn in place at the
take-off point. When no candidate is feasible the loop recovers (turn in place, then back-track to
earlier viewpoints, then hover) and logs it; it never crashes on that.

This is the only module that knows all the others. After every frame it writes the per-frame CSV
and a checkpoint, so `Mission.resume(run_dir)` continues a killed run and ends with the same result
as an uninterrupted one (OMPL is reseeded per step from the seed and the frame index, so resumed
planning draws the same random numbers).
"""

from __future__ import annotations

import csv
import io
import logging
import math
import time
from collections import Counter
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import NoReturn

import numpy as np

from flightrecon import provenance, run_folder, run_lock, threads
from flightrecon.active.diagnosis import move_kind
from flightrecon.active.protocol import MapView, Observation, Selector
from flightrecon.active.registry import make_selector
from flightrecon.checkpoint import load_checkpoint, refuse_legacy, save_checkpoint
from flightrecon.config import ScenarioConfig, to_toml
from flightrecon.control.trajectory import FlatState
from flightrecon.dataset import DatasetWriter, write_trajectory_csv
from flightrecon.errors import ConfigError, DataError, FlightReconError
from flightrecon.evaluation.coverage import SurfaceCoverage
from flightrecon.evaluation.visible_surface import visible_surface
from flightrecon.fileio import write_json, write_text
from flightrecon.geometry import camera_pose_from_body, make_pose, rot_z
from flightrecon.mapping.mapper import OnlineMapper
from flightrecon.mapping.ply import save_map
from flightrecon.planning.feasibility import CandidateResult, Planner
from flightrecon.planning.paths import seed_ompl
from flightrecon.recording import NullRecorder, Stage, open_recorder
from flightrecon.rig import build_rig
from flightrecon.scenario import load_config
from flightrecon.sim.flight import Flight, FlightDiverged
from flightrecon.sim.quadrotor import camera_offset
from flightrecon.sim.safety import ClearanceMonitor, FlightContact

log = logging.getLogger(__name__)

RELIABLE_EMA, RELIABLE_STOP = 0.95, 0.75
DIAGNOSIS_SURFACE_SAMPLES = 200_000  # ground-truth surface samples of output.diagnose's coverage
FRAME_COLUMNS = ("frame", "sim_time", "t_capture", "t_map", "t_select_update", "t_plan", "t_score",
                 "t_fly_sim", "n_splats", "n_candidates", "n_feasible", "n_ompl", "chosen_score",
                 "flight_time", "flight_distance", "recovery", "frame_psnr", "frame_depth_l1_cm",
                 "eval_psnr", "eval_depth_l1_cm", "min_clearance", "contacts", "reliable_share_ema", "threads")


@dataclass
class MissionState:
    """Everything the loop itself carries between frames (the components carry their own)."""

    frame: int = 0
    records: list = field(default_factory=list)
    events: list = field(default_factory=list)
    visited: list = field(default_factory=list)  # (position, yaw) of every capture
    flight_distance: float = 0.0
    wall_time: float = 0.0
    reliable_ema: float = 0.0  # EMA of the selector's stopping statistic (see `_update_stopping`)
    told_no_room: bool = False  # the user was told the drone cannot leave its take-off point
    dataset_frames: list = field(default_factory=list)  # output.dataset: the transforms.json entries so far
    coverage: SurfaceCoverage | None = None  # output.diagnose: what the captured depth has reached
    diagnosis: list = field(default_factory=list)  # output.diagnose: one row per frame


class Mission:
    """One active-reconstruction flight; `run()` goes until the frame budget, checkpointing."""

    def __init__(self, cfg: ScenarioConfig, run_dir: str | Path, *, progress: bool = True) -> None:
        self.cfg = cfg
        self.run_dir = Path(run_dir)
        self.progress = progress
        self.rig = rig = build_rig(cfg)
        self.flight = Flight.from_world(rig.world, cfg, ClearanceMonitor(rig.scene.trimesh, cfg.drone.body_radius))
        self.planner = Planner(cfg, rig.workspace, rig.scene.trimesh, rig.start)
        self.mapper = OnlineMapper(cfg.mapper, near=cfg.camera.near, far=cfg.camera.far, seed=cfg.seed)
        self.free_cores = threads.FreeCores()
        self.selector = make_selector(cfg)
        self.view = MapView(self.mapper, self.selector.columns)
        if cfg.budget.stop_on_reliability and not self.has_stopping_statistic:
            raise ConfigError(f"config key 'budget.stop_on_reliability': selector {cfg.selector.method!r} keeps no "
                              "stopping statistic; set it to false or choose a selector that has one")
        self.selector.attach_scene(rig.scene.bounds)
        self.evaluation = rig.evaluation_set()
        self.state = MissionState()
        if cfg.output.diagnose:
            visible = visible_surface(rig.scene, rig.free, DIAGNOSIS_SURFACE_SAMPLES)
            self.state.coverage = SurfaceCoverage(visible.points)
        self.live_viewer = False  # `fly --rerun`: stream the recording to a viewer as well
        self.allow_code_change = False  # resume a run whose earlier frames ran other code (recorded)
        self.recorder = NullRecorder()  # the recording, opened by the first step of this process
        self._begun = False
        self.dataset: DatasetWriter | None = None  # output.dataset, opened by the first step

    # ------------------------------------------------------------------ run control
    @classmethod
    def resume(cls, run_dir: str | Path, *, progress: bool = True) -> "Mission":
        """Rebuild the mission from run_dir/config.toml and restore its last checkpoint."""
        run_dir = Path(run_dir)
        cfg_path = run_dir / run_folder.CONFIG
        ckpt = run_dir / run_folder.CHECKPOINT
        if not cfg_path.is_file():
            raise FlightReconError(f"cannot resume: {cfg_path} not found (is {run_dir} a run folder?)")
        refuse_legacy(run_dir)
        mission = cls(load_config(cfg_path), run_dir, progress=progress)
        (run_dir / run_folder.FAILED).unlink(missing_ok=True)  # flying on: an earlier stop no longer stands
        if ckpt.is_file():
            mission._load_checkpoint(ckpt)
        return mission

    def run(self) -> dict:
        """Fly until the frame budget (or the stopping rule); returns the final metrics (metrics.json).
        Raises RunInUse, before writing anything, while another process flies the same run folder."""
        with run_lock.claim(self.run_dir):
            bar = _progress(self.cfg.budget.frames, self.state.frame, self.progress)
            while not self.done:
                bar.update(self.step())
                if self.stopping_rule_met:
                    self._event(f"frame {self.state.frame - 1}: stopping rule met (EMA of the reliable share "
                                f"{self.state.reliable_ema:.3f} > {RELIABLE_STOP})")
                    self._save_frame_outputs()
                    break
            bar.close()
            return self.finish()

    @property
    def done(self) -> bool:
        """The frame budget is spent."""
        return self.state.frame >= self.cfg.budget.frames

    @property
    def stopping_rule_met(self) -> bool:
        return self.cfg.budget.stop_on_reliability and self.state.reliable_ema > RELIABLE_STOP

    def step(self) -> dict:
        """One frame of the loop: capture, map, update the selector, then (except at the budget's last
        frame) plan, score and fly to the chosen view. The first call takes off. Returns the frame's row
        of frames.csv; the frame's outputs and checkpoint are written before it returns."""
        if self.done:
            raise FlightReconError(f"the frame budget ({self.cfg.budget.frames}) is spent; `finish()` writes the "
                                   "map and metrics")
        if not self._begun:
            self._begin()
        t0 = time.perf_counter()
        row = _plain(self._step(last=self.state.frame == self.cfg.budget.frames - 1))
        if self.state.diagnosis:
            self.state.diagnosis[-1] = _plain(self.state.diagnosis[-1])
        self.state.wall_time += time.perf_counter() - t0
        self.state.records.append(row)
        self.recorder.frame_done(row)
        self.state.frame += 1
        self._save_frame_outputs()
        if self.cfg.output.checkpoint:
            self._save_checkpoint()
        return row

    def _begin(self) -> None:
        """Before the first step of this process: the run folder, its config and provenance, the take-off
        (a new run), and the recording."""
        self._begun = True
        refuse_legacy(self.run_dir)  # a folder an older FlightRecon flew in: never start beside its checkpoint
        self.run_dir.mkdir(parents=True, exist_ok=True)
        write_text(self.run_dir / run_folder.CONFIG, to_toml(self.cfg))
        provenance.begin_segment(self.run_dir, self.state.frame, self.allow_code_change)
        start = self.state.frame
        if start == 0:
            self._take_off()
        if self.cfg.output.dataset:
            c = self.cfg.camera
            self.dataset = DatasetWriter(self.run_dir / run_folder.DATASET, self.rig.K, c.width, c.height)
            self.dataset.frames = self.state.dataset_frames  # the entries of frames before a resume
        self.recorder = open_recorder(self.cfg, self.run_dir, Stage(self.rig.scene, self.rig.workspace, self.rig.K),
                                      frame=start, sim_time=self.flight.time, live=self.live_viewer,
                                      takeoff=self.flight.log.columns() if start == 0 else None)

    # ------------------------------------------------------------------ one step
    def _take_off(self) -> None:
        """Climb from the floor to the take-off point (moved off the default when that is unsafe: said)."""
        if self.rig.takeoff.moved:
            self._event(self.rig.takeoff.note, logging.WARNING)
        self.flight.start(self.rig.takeoff.ground, 0.0)
        self.flight.go_to(self.rig.start, 0.0)
        self.flight.wait_until_arrived()

    def _step(self, last: bool) -> dict:
        cfg = self.cfg
        row: dict = {"frame": self.state.frame}
        t = time.perf_counter()
        rgb, depth, T_wc, T_true = self.flight.capture(self.rig.camera)
        if self.dataset is not None:
            self.dataset.add(rgb, depth, T_wc, self.flight.time, T_true)
            self.dataset.write_index()
        body = self.flight.state
        self.state.visited.append((body.position.copy(), float(body.yaw)))
        row["t_capture"] = time.perf_counter() - t
        row["sim_time"] = self.flight.time

        row["threads"] = self.free_cores.update()
        t = time.perf_counter()
        with self._stage("mapping"):
            self.mapper.add_frame(rgb, depth, self.rig.K, T_wc)
            self.mapper.map.check_finite()
        row["t_map"] = time.perf_counter() - t
        t = time.perf_counter()
        with self._stage("selector update"):
            # the one render of the map at the captured pose: selector update, frame quality, recording
            obs = Observation(self.state.frame, rgb, depth, self.rig.K, T_wc,
                              self.mapper.render_capture(T_wc, self.rig.K, depth.shape[1], depth.shape[0]))
            self.selector.observe(self.view, obs)
        row["t_select_update"] = time.perf_counter() - t
        row["reliable_share_ema"] = self._update_stopping()
        row["n_splats"] = len(self.mapper.map)
        with self._stage("frame quality"):
            row["frame_psnr"], row["frame_depth_l1_cm"] = self.evaluation.frame_quality(obs.view.output, rgb, depth)
        self.recorder.capture(self.state.frame, self.flight.time, obs, self.mapper.map, last)
        self.planner.integrate(depth, self.rig.K, T_wc, body_position=body.position)
        if self.state.coverage is not None:
            seen, overlap = self.state.coverage.add_frame(depth, self.rig.K, T_wc)
            self.state.diagnosis.append({"frame": self.state.frame, "surface_seen": seen, "overlap": overlap})

        every = cfg.evaluation.every
        if last or (every > 0 and self.state.frame % every == 0):
            with self._stage("evaluation"):
                q = self.evaluation.evaluate(self.mapper)
            row["eval_psnr"], row["eval_depth_l1_cm"] = q["psnr"], q["depth_l1_cm"]
            if cfg.evaluation.snapshots and not last:  # mesh metrics need a TSDF: `eval` scores them later
                save_map(self.mapper.map, run_folder.snapshot_path(self.run_dir, self.state.frame),
                         extras=cfg.output.ply_extras, columns=self.selector.columns)
        if last:
            return row
        self._choose_and_fly(row)
        return row

    @contextmanager
    def _stage(self, name: str):
        """Name the frame and the stage in a data error raised inside (a NaN in the map, say)."""
        try:
            yield
        except DataError as exc:
            raise DataError(f"frame {self.state.frame}, stage {name}: {exc} (run folder {self.run_dir} keeps "
                            "the frames before it)") from None

    @property
    def has_stopping_statistic(self) -> bool:
        return type(self.selector).stopping_statistic is not Selector.stopping_statistic

    def _update_stopping(self) -> float:
        """GauSS-MI's stopping rule: an exponential moving average (0.95) of the share of splats the
        selector deems reliable; `budget.stop_on_reliability` stops past 75%. NaN for a selector
        without the statistic."""
        share = self.selector.stopping_statistic(self.view)
        if share is None:
            return math.nan
        self.state.reliable_ema = RELIABLE_EMA * self.state.reliable_ema + (1 - RELIABLE_EMA) * share
        return self.state.reliable_ema

    def _rest_state(self) -> FlatState:
        s = self.flight.state
        return FlatState(s.position.copy(), np.zeros(3), np.zeros(3), float(s.yaw), 0.0)

    def plan_candidates(self) -> list[CandidateResult]:
        """The candidate views of this step, checked by the planner from where the drone hovers: the
        shared library around it, or the selector's own candidates when it proposes them."""
        start = self._rest_state()
        own = self.selector.propose(self.view, start.position.copy(), start.yaw, self.state.frame)
        if own is None:
            return self.planner.check_library(start)
        positions, yaws = own
        return self.planner.check(start, positions, yaws) if len(positions) else []

    def score_candidates(self, candidates: list[CandidateResult]) -> np.ndarray:
        """The selector's scores [C] of planned candidates (higher is better; the loop flies to the argmax).
        A seeded selector such as random draws from its generator on every call."""
        lengths = np.array([r.length for r in candidates])
        with self._stage("scoring"):
            return np.asarray(self.selector.score(self.view, self.candidate_poses(candidates), lengths), float)

    def _choose_and_fly(self, row: dict) -> None:
        seed_ompl(self.cfg.seed * 1_000_003 + self.state.frame)
        start = self._rest_state()
        t = time.perf_counter()
        if self.state.frame + 1 < self.cfg.budget.initial_views:
            step = 2 * math.pi / self.cfg.budget.initial_views
            results = self.planner.check(start, start.position[None], np.array([start.yaw + step]))
        else:
            results = self.plan_candidates()
        row["t_plan"] = time.perf_counter() - t
        feasible = [r for r in results if r.feasible]
        row["n_candidates"], row["n_feasible"] = len(results), len(feasible)
        row["n_ompl"] = sum(r.used_ompl for r in results)
        t = time.perf_counter()
        chosen: CandidateResult | None = None
        if len(feasible) == 1:
            chosen, row["chosen_score"] = feasible[0], math.nan
        elif feasible:
            scores = self.score_candidates(feasible)
            best = int(np.argmax(scores))
            chosen, row["chosen_score"] = feasible[best], float(scores[best])
            if self.state.coverage is not None:
                self._diagnose_choice(chosen, scores)
        row["t_score"] = time.perf_counter() - t
        row["recovery"] = ""
        if chosen is None:
            chosen = self._recover(start, results, row)
        self.recorder.candidates(results, feasible, scores if len(feasible) > 1 else None, chosen)
        t = time.perf_counter()
        before = len(self.flight.log)
        self.flight.stop_on_contact = self.cfg.sim.on_contact == "stop"  # airborne: the take-off is behind
        try:
            if chosen is not None:
                self.flight.fly(chosen.trajectory)
                if not self.flight.wait_until_arrived():
                    self._event(f"frame {self.state.frame}: did not settle at the chosen view; capturing anyway")
                row["flight_time"] = float(chosen.duration)
                self.state.flight_distance += float(chosen.length)
            else:
                self.flight.hover(1.0)
                row["flight_time"] = 1.0
        except FlightDiverged as exc:
            raise FlightReconError(f"{exc} (run folder {self.run_dir} keeps the frames so far)") from None
        except FlightContact as exc:
            self._stop_for_contact(exc)
        row["flight_distance"] = self.state.flight_distance
        row["t_fly_sim"] = time.perf_counter() - t
        flown = self.flight.log.slice_from(before)
        self.recorder.flight(flown, chosen)
        clear = flown.columns()["clearance"] if len(flown) else np.array([np.nan])
        row["min_clearance"] = float(np.nanmin(clear)) if np.isfinite(clear).any() else math.nan
        row["contacts"] = len(self.flight.log.events)
        for ev in flown.events:
            self._event(f"frame {self.state.frame}: contact {ev.describe()}")

    def _stop_for_contact(self, exc: FlightContact) -> NoReturn:
        """sim.on_contact = "stop": end the run at the frame whose flight touched the scene, leaving
        the frames before it, the event and failed.txt in the run folder (a sweep skips it and reports it)."""
        text = (f"frame {self.state.frame}: the flight stopped: {exc}. The planner keeps planner.safety_margin "
                "beyond drone.body_radius from what it has mapped; raise it, or set sim.on_contact = "
                "\"continue\" to fly on and count the contacts in metrics.json")
        self._event(text)  # (the error raised says it to the user)
        self._save_frame_outputs()
        write_text(self.run_dir / run_folder.FAILED, text + "\n")
        raise FlightContact(f"{text} (run folder {self.run_dir} keeps the frames before it)", exc.event) from None

    def _diagnose_choice(self, chosen: CandidateResult, scores: np.ndarray) -> None:
        """output.diagnose: the move, the best score over the median, and the selector's own diagnosis
        of the chosen view (2D GauSS-MI: its MI split by kind of splat)."""
        s = self.flight.state
        diag = self.state.diagnosis[-1]
        diag["move"] = move_kind(s.position, float(s.yaw), chosen.position, float(chosen.yaw))
        diag["best_over_median"] = float(scores.max() / np.median(scores)) if np.median(scores) > 0 else math.nan
        diag.update(self.selector.diagnose(self.view, self.candidate_poses([chosen])[0]))

    def _recover(self, start: FlatState, results: list[CandidateResult], row: dict) -> CandidateResult | None:
        """No feasible candidate: turn in place, else back-track to an earlier viewpoint, else hover."""
        reasons = dict(Counter(r.reason for r in results))
        turns = start.yaw + np.array([math.pi / 2, -math.pi / 2, math.pi])
        for r in self.planner.check(start, np.repeat(start.position[None], 3, 0), turns):
            if r.feasible:
                row["recovery"] = "turn"
                self._event(f"frame {self.state.frame}: no feasible candidate ({reasons}); turning in place")
                return r
        back = self.state.visited[-2::-1][:5]
        if back:
            pos = np.array([p for p, _ in back])
            yaws = np.array([y for _, y in back])
            for r in self.planner.check(start, pos, yaws):
                if r.feasible:
                    row["recovery"] = "backtrack"
                    self._event(f"frame {self.state.frame}: no feasible candidate ({reasons}); back-tracking")
                    return r
        row["recovery"] = "hover"
        self._event(f"frame {self.state.frame}: no feasible candidate or recovery ({reasons}); hovering")
        if self.state.flight_distance == 0.0 and not self.state.told_no_room:
            self._tell_no_room(reasons)
        return None

    def _tell_no_room(self, reasons: dict) -> None:
        """Once per run: the drone has not moved and nothing around it is feasible, which is almost
        always a workspace that leaves it no room (an open scan, a wrong up axis or unit scale)."""
        self.state.told_no_room = True
        lo, hi = (np.round(b, 2).tolist() for b in self.rig.workspace)
        text = (f"frame {self.state.frame}: the drone cannot leave its take-off point "
                f"{np.round(self.rig.start, 2).tolist()}: no candidate or recovery is feasible ({reasons}). "
                f"Candidates must lie in the workspace {lo} .. {hi} (the scene's floor to its ceiling, or "
                f"planner.max_height above the floor without one, shrunk by the clearance "
                f"{self.planner.settings.required_clearance:.2f} m). Change planner.max_height, "
                "sim.takeoff_height, planner.safety_margin or drone.body_radius, or check scene.up_axis "
                "and scene.unit_scale (`flightrecon scene info` shows the floor, ceiling and workspace)")
        self._event(text, logging.WARNING)

    def candidate_poses(self, results: list[CandidateResult]) -> np.ndarray:
        """Camera T_wc [C,4,4] the drone would have at each candidate (body at rest, level)."""
        pitch, offset = self.cfg.camera.pitch_deg, camera_offset(self.cfg.drone.arm_length)
        return np.stack([camera_pose_from_body(make_pose(rot_z(r.yaw), r.position), offset, pitch)
                         for r in results])

    def _event(self, text: str, level: int = logging.INFO) -> None:
        log.log(level, text)
        self.state.events.append(text)
        self.recorder.event(text)

    # ------------------------------------------------------------------ outputs
    def _save_frame_outputs(self) -> None:
        write_text(self.run_dir / run_folder.FRAMES, _csv_text(self.state.records, FRAME_COLUMNS))
        write_text(self.run_dir / run_folder.EVENTS, "".join(e + "\n" for e in self.state.events))
        if self.state.diagnosis:
            names = list(dict.fromkeys(k for r in self.state.diagnosis for k in r))
            write_text(self.run_dir / run_folder.DIAGNOSIS, _csv_text(self.state.diagnosis, names))

    def finish(self) -> dict:
        """Close the recording and write the final map, trajectory and metrics.json; returns the metrics."""
        self.recorder.close()
        save_map(self.mapper.map, self.run_dir / run_folder.MAP, extras=self.cfg.output.ply_extras,
                 columns=self.selector.columns)
        write_trajectory_csv(self.run_dir / run_folder.TRAJECTORY, self.flight.log.columns())
        if self.dataset is not None:
            self.dataset.close(self.flight.log.columns())
        final = self.evaluation.evaluate(self.mapper)
        rec = self.state.records
        metrics = {
            "scenario": self.cfg.name, "method": self.cfg.selector.method, "seed": self.cfg.seed,
            "code_states": provenance.code_states(self.run_dir),
            "frames": len(rec), "splats": len(self.mapper.map), "splats_pruned": self.mapper.pruned,
            "map_mb": (self.run_dir / run_folder.MAP).stat().st_size / 1e6,
            "flight_distance_m": self.state.flight_distance, "sim_time_s": self.flight.time,
            "wall_time_s": self.state.wall_time, "contacts": len(self.flight.log.events),
            "contact_frames": _contact_frames(rec),
            "recoveries": sum(1 for r in rec if r.get("recovery")),
            "eval": final,
            "mean_times_s": {k: float(np.mean([r[k] for r in rec if k in r]))
                             for k in ("t_capture", "t_map", "t_select_update", "t_plan", "t_score", "t_fly_sim")
                             if any(k in r for r in rec)},
        }
        write_json(self.run_dir / run_folder.METRICS, metrics)
        return metrics

    # ------------------------------------------------------------------ checkpoints
    def _save_checkpoint(self) -> None:
        """The state of every component after this frame, as arrays and JSON (flightrecon.checkpoint)."""
        st = self.state
        mission = {"frame": st.frame, "records": st.records, "events": st.events,
                   "visited_positions": np.array([p for p, _ in st.visited], float).reshape(-1, 3),
                   "visited_yaws": [y for _, y in st.visited], "flight_distance": st.flight_distance,
                   "wall_time": st.wall_time, "reliable_ema": st.reliable_ema, "told_no_room": st.told_no_room,
                   "dataset_frames": st.dataset_frames, "diagnosis": st.diagnosis,
                   "coverage": st.coverage.get_state() if st.coverage is not None else None}
        save_checkpoint(self.run_dir / run_folder.CHECKPOINT,
                        {"flight": self.flight.get_state(), "mapper": self.mapper.get_state(),
                         "planner": self.planner.get_state(), "selector": self.selector.get_state(),
                         "mission": mission})

    def _load_checkpoint(self, path: Path) -> None:
        state = load_checkpoint(path)
        self.flight.set_state(state["flight"])
        self.mapper.set_state(state["mapper"])  # the selector's columns come back with the map
        self.planner.set_state(state["planner"])
        self.selector.set_state(state["selector"])
        m = state["mission"]
        coverage = self.state.coverage
        if coverage is not None and m["coverage"] is not None:
            coverage.set_state(m["coverage"])
        self.state = MissionState(
            frame=m["frame"], records=m["records"], events=m["events"],
            visited=[(np.asarray(p, float), float(y)) for p, y in zip(m["visited_positions"], m["visited_yaws"])],
            flight_distance=m["flight_distance"], wall_time=m["wall_time"], reliable_ema=m["reliable_ema"],
            told_no_room=m["told_no_room"], dataset_frames=m["dataset_frames"], coverage=coverage,
            diagnosis=m["diagnosis"])


class _progress:
    """A progress bar with the live figures a user watches (tqdm), or nothing."""

    def __init__(self, total: int, done: int, enabled: bool) -> None:
        self.bar = None
        if enabled:
            from tqdm import tqdm

            from flightrecon.metric_defs import METRICS

            self.bar = tqdm(total=total, initial=done, unit="frame", dynamic_ncols=True)
            self.psnr = METRICS["psnr"]

    def update(self, row: dict) -> None:
        if self.bar is None:
            return
        post = {"splats": row.get("n_splats"), "feasible": row.get("n_feasible"),  # PSNRs blank where none
                "psnr": self.psnr.format(row.get("frame_psnr"), missing=""),
                "eval": self.psnr.format(row.get("eval_psnr"), missing="")}
        self.bar.set_postfix({k: v for k, v in post.items() if v not in (None, "")}, refresh=False)
        self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _contact_frames(rows: list[dict]) -> list[int]:
    """Frames whose flight touched the scene (frame 0's includes the take-off): where the running
    count of contacts in frames.csv grows."""
    frames, seen = [], 0
    for r in rows:
        if r.get("contacts", seen) > seen:
            frames.append(r["frame"])
            seen = r["contacts"]
    return frames


def _plain(row: dict) -> dict:
    """A row with numpy scalars as Python ones: what checkpoints store, and how the CSV prints them."""
    return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in row.items()}


def _csv_text(rows: list[dict], columns) -> str:
    """Rows as CSV with the given columns (others ignored, missing ones empty), floats to 6 digits."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(columns), restval="", extrasaction="ignore")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    return buf.getvalue()
