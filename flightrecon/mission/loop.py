"""The closed loop of active reconstruction (docs/architecture.md, "One active step").

Each step: the drone has settled at a viewpoint and captures RGB-D at its actual simulated pose;
the mapper adds and optimizes splats; the selector updates its state (reliability for 2D
GauSS-MI); the occupancy map takes the depth; the planner checks the candidate library around the
drone; the selector scores the feasible candidates; the controller flies the best one's trajectory
in the fixed-rate cycle until arrival. The policies around it are modules of their own: the
take-off and first views (`launch`), the way out when no candidate is feasible (`recovery`), the
stopping rule (`stopping`), output.diagnose (`diagnosis`).

This is the only module that knows all the others. After every frame it writes the per-frame CSV
and a checkpoint, so `Mission.resume(run_dir)` continues a killed run and ends with the same result
as an uninterrupted one (OMPL is reseeded per step from the seed and the frame index, so resumed
planning draws the same random numbers).
"""

from __future__ import annotations

import logging
import math
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, NoReturn

import numpy as np

from flightrecon import profiling, provenance, run_folder, run_lock, threads
from flightrecon.active.protocol import MapView, Observation
from flightrecon.active.registry import make_selector
from flightrecon.checkpoint import load_checkpoint, refuse_legacy, save_checkpoint
from flightrecon.config import ScenarioConfig, to_toml
from flightrecon.control.trajectory import FlatState
from flightrecon.dataset import DatasetWriter, write_trajectory_csv
from flightrecon.errors import DataError, FlightReconError
from flightrecon.fileio import write_text
from flightrecon.flight_profile import mapping_columns
from flightrecon.geometry import camera_pose_from_body, make_pose, rot_z
from flightrecon.mapping.mapper import OnlineMapper
from flightrecon.mapping.ply import save_map
from flightrecon.mission import diagnosis, launch, outputs, recovery, stopping
from flightrecon.mission.progress import Progress
from flightrecon.mission.state import MissionState
from flightrecon.planning.feasibility import CandidateResult, Planner
from flightrecon.planning.paths import seed_ompl
from flightrecon.recording import NullRecorder, Stage, open_recorder
from flightrecon.rig import build_rig
from flightrecon.scenario import load_config
from flightrecon.sim.camera import reduction_for_width
from flightrecon.sim.flight import Flight, FlightDiverged
from flightrecon.sim.quadrotor import camera_offset
from flightrecon.sim.safety import ClearanceMonitor, FlightContact

log = logging.getLogger(__name__)
REHEARSALS = 10  # best candidates whose flights are rehearsed before the step falls back to its way out


class Mission:
    """One active-reconstruction flight; `run()` goes until the frame budget, checkpointing."""

    def __init__(self, cfg: ScenarioConfig, run_dir: str | Path, *, progress: bool = True) -> None:
        self.cfg = cfg
        self.run_dir = Path(run_dir)
        self.progress = progress
        self.rig = rig = build_rig(cfg)
        self.flight = Flight.from_world(rig.world, cfg, ClearanceMonitor(rig.scene.trimesh, cfg.drone.body_radius))
        self.planner = Planner(cfg, rig.workspace, rig.scene.trimesh, rig.start)
        self.look_reduce = reduction_for_width(cfg.camera.width, cfg.camera.height, cfg.planner.look_width)
        if cfg.planner.look_hz > 0:
            self.flight.watch(self._look, 1.0 / cfg.planner.look_hz)
        self.mapper = OnlineMapper(cfg.mapper, near=cfg.camera.near, far=cfg.camera.far, seed=cfg.seed)
        self.free_cores = threads.FreeCores()
        self.selector = make_selector(cfg)
        self.view = MapView(self.mapper, self.selector.columns)
        stopping.check_rule_allowed(cfg, self.selector)
        self.selector.attach_scene(rig.scene.bounds)
        self.evaluation = rig.evaluation_set()
        self.state = MissionState()
        if cfg.output.diagnose:
            self.state.coverage = diagnosis.surface_coverage(rig)
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
            bar = Progress(self.cfg.budget.frames, self.state.frame, self.progress)
            while not self.done:
                bar.update(self.step())
                if stopping.rule_met(self.cfg, self.state.reliable_ema):
                    self._event(stopping.stop_text(self.state.frame - 1, self.state.reliable_ema))
                    outputs.save_frame_outputs(self.run_dir, self.state)
                    break
            bar.close()
            return self.finish()

    @property
    def done(self) -> bool:
        """The frame budget is spent."""
        return self.state.frame >= self.cfg.budget.frames

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
        row = outputs.plain(self._step(last=self.state.frame == self.cfg.budget.frames - 1))
        if self.state.diagnosis:
            self.state.diagnosis[-1] = outputs.plain(self.state.diagnosis[-1])
        self.state.wall_time += time.perf_counter() - t0
        self.state.records.append(row)
        self.recorder.frame_done(row)
        self.state.frame += 1
        outputs.save_frame_outputs(self.run_dir, self.state)
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

    def _take_off(self) -> None:
        """Climb from the floor to the take-off point (moved off the default when that is unsafe: said)."""
        if self.rig.takeoff.moved:
            self._event(self.rig.takeoff.note, logging.WARNING)
        launch.climb(self.flight, self.rig.takeoff, self.rig.start)

    def _look(self) -> None:
        """A depth frame the camera streams in flight, for the occupancy map alone (planner.look_hz)."""
        depth, T_wc = self.flight.capture_depth(self.rig.camera, self.look_reduce)
        self.planner.integrate(depth, self.rig.camera.intrinsics_at(self.look_reduce), T_wc,
                               body_position=self.flight.state.position)

    # ------------------------------------------------------------------ one step
    def _step(self, last: bool) -> dict:
        row: dict = {"frame": self.state.frame}
        obs = self._capture_and_map(row, last)
        self.planner.integrate(obs.depth, self.rig.K, obs.T_wc, body_position=self.flight.state.position)
        if self.state.coverage is not None:
            self.state.diagnosis.append(diagnosis.frame_row(self.state.coverage, self.state.frame, obs.depth,
                                                            self.rig.K, obs.T_wc))
        every = self.cfg.evaluation.every
        if last or (every > 0 and self.state.frame % every == 0):
            self._evaluate(row, last)
        if not last:
            self._fly(self._choose(row), row)
        return row

    def _capture_and_map(self, row: dict, last: bool) -> Observation:
        """Capture at the drone's pose, map the frame, let the selector observe it; the frame's quality."""
        t = time.perf_counter()
        rgb, depth, T_wc, T_true = self.flight.capture(self.rig.camera)
        if self.dataset is not None:
            self.dataset.add(rgb, depth, T_wc, self.flight.time, T_true)
            self.dataset.write_index()
        body = self.flight.state
        self.state.visited.append((body.position.copy(), float(body.yaw)))
        row["t_capture"], row["sim_time"] = time.perf_counter() - t, self.flight.time
        row["threads"] = self.free_cores.update()
        t = time.perf_counter()
        with self._stage("mapping"), profiling.profiling() as prof:
            self.mapper.add_frame(rgb, depth, self.rig.K, T_wc)
            self.mapper.map.check_finite()
        row["t_map"] = time.perf_counter() - t
        row.update(mapping_columns(prof))
        t = time.perf_counter()
        with self._stage("selector update"):
            # the one render of the map at the captured pose: selector update, frame quality, recording
            obs = Observation(self.state.frame, rgb, depth, self.rig.K, T_wc,
                              self.mapper.render_capture(T_wc, self.rig.K, depth.shape[1], depth.shape[0]))
            self.selector.observe(self.view, obs)
        row["t_select_update"] = time.perf_counter() - t
        row["reliable_share_ema"] = stopping.update(self.selector, self.view, self.state)
        row["n_splats"] = len(self.mapper.map)
        with self._stage("frame quality"):
            row["frame_psnr"], row["frame_depth_l1_cm"] = self.evaluation.frame_quality(obs.view.output, rgb, depth)
        self.recorder.capture(self.state.frame, self.flight.time, obs, self.mapper.map, last)
        return obs

    def _evaluate(self, row: dict, last: bool) -> None:
        """An in-flight evaluation on the scene's evaluation views (and a map snapshot, with evaluation.snapshots)."""
        with self._stage("evaluation"):
            q = self.evaluation.evaluate(self.mapper)
        row["eval_psnr"], row["eval_depth_l1_cm"] = q["psnr"], q["depth_l1_cm"]
        if self.cfg.evaluation.snapshots and not last:  # mesh metrics need a TSDF: `eval` scores them later
            save_map(self.mapper.map, run_folder.snapshot_path(self.run_dir, self.state.frame),
                     extras=self.cfg.output.ply_extras, columns=self.selector.columns)

    def _choose(self, row: dict) -> CandidateResult | None:
        """Plan the candidates, score the feasible ones and pick the best (a way out when none is
        feasible: `recovery`); None: hover."""
        seed_ompl(self.cfg.seed * 1_000_003 + self.state.frame)
        start = self._rest_state()
        t = time.perf_counter()
        results = launch.initial_turn(self.planner, start, self.state.frame, self.cfg.budget.initial_views)
        if results is None:
            results = self.plan_candidates()
        row["t_plan"] = time.perf_counter() - t
        feasible = [r for r in results if r.feasible]
        row["n_candidates"], row["n_feasible"] = len(results), len(feasible)
        row["n_ompl"] = sum(r.used_ompl for r in results)
        t = time.perf_counter()
        ranked, scores, order = feasible, None, None
        if len(feasible) > 1:
            scores = self.score_candidates(feasible)
            order = np.argsort(-np.asarray(scores), kind="stable")
            ranked = [feasible[i] for i in order]
        row["t_score"] = time.perf_counter() - t
        t = time.perf_counter()
        chosen, passed_over = self._first_tracked(ranked, start)
        row["t_rehearse"], row["n_tracking_rejected"] = time.perf_counter() - t, passed_over
        scored = chosen is not None and order is not None
        row["chosen_score"] = float(scores[order[passed_over]]) if scored else math.nan
        if chosen is not None and scores is not None and self.state.coverage is not None:
            s = self.flight.state
            self.state.diagnosis[-1].update(diagnosis.choice_columns(
                self.selector, self.view, s.position, float(s.yaw), chosen, self.candidate_poses([chosen])[0], scores))
        row["recovery"] = ""
        if chosen is None:
            chosen = self._recover(start, results, row)
            if chosen is not None and self._first_tracked([chosen], start)[0] is None:
                self._event(f"frame {self.state.frame}: the way out ({row['recovery']}) would not keep the clearance "
                            "when flown: hovering instead")
                chosen = None
        self.recorder.candidates(results, feasible, scores, chosen)
        return chosen

    def _first_tracked(self, ranked: list[CandidateResult], start: FlatState) -> tuple[CandidateResult | None, int]:
        """The first of `ranked` (best first, at most REHEARSALS of them) whose flight, rehearsed with
        the controller, keeps the clearance its planned trajectory keeps; and how many were passed
        over. The planner checks the reference; the drone lags it at corners and overshoots when it
        stops (up to about 5 cm), which took flights inside their safety margin."""
        for k, candidate in enumerate(ranked[:REHEARSALS]):
            try:
                path = self.flight.rehearse(candidate.trajectory)
            except FlightDiverged as exc:
                raise FlightReconError(f"{exc} (rehearsing frame {self.state.frame}'s flight; run folder "
                                       f"{self.run_dir} keeps the frames so far)") from None
            if self.planner.keeps_clearance(path, start.position):
                return candidate, k
        return None, min(len(ranked), REHEARSALS)

    def _fly(self, chosen: CandidateResult | None, row: dict) -> None:
        """Fly to the chosen view and settle (hover a second without one); the flight's columns of the row."""
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

    def _recover(self, start: FlatState, results: list[CandidateResult], row: dict) -> CandidateResult | None:
        """No feasible candidate: the way out (`recovery`), said; once per run, why the drone cannot
        leave its take-off point when it has not moved."""
        way = recovery.recover(self.planner, start, results, self.state.visited, self.state.frame)
        row["recovery"] = way.kind
        self._event(way.text)
        if way.choice is None and self.state.flight_distance == 0.0 and not self.state.told_no_room:
            self.state.told_no_room = True
            self._event(recovery.no_room_text(self.state.frame, self.rig.start, self.rig.workspace,
                                              self.planner.settings.required_clearance, way.reasons), logging.WARNING)
        return way.choice

    def _stop_for_contact(self, exc: FlightContact) -> NoReturn:
        """sim.on_contact = "stop": end the run at the frame whose flight touched the scene, leaving
        the frames before it, the event and failed.txt in the run folder (a sweep skips it and reports it)."""
        text = (f"frame {self.state.frame}: the flight stopped: {exc}. The planner keeps planner.safety_margin "
                "beyond drone.body_radius from what it has mapped; raise it, or set sim.on_contact = "
                "\"continue\" to fly on and count the contacts in metrics.json")
        self._event(text)  # (the error raised says it to the user)
        outputs.save_frame_outputs(self.run_dir, self.state)
        write_text(self.run_dir / run_folder.FAILED, text + "\n")
        raise FlightContact(f"{text} (run folder {self.run_dir} keeps the frames before it)", exc.event) from None

    # ------------------------------------------------------------------ candidates
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

    def candidate_poses(self, results: list[CandidateResult]) -> np.ndarray:
        """Camera T_wc [C,4,4] the drone would have at each candidate (body at rest, level)."""
        pitch, offset = self.cfg.camera.pitch_deg, camera_offset(self.cfg.drone.arm_length)
        return np.stack([camera_pose_from_body(make_pose(rot_z(r.yaw), r.position), offset, pitch)
                         for r in results])

    # ------------------------------------------------------------------ events, outputs, checkpoints
    @contextmanager
    def _stage(self, name: str) -> Iterator[None]:
        """Name the frame and the stage in a data error raised inside (a NaN in the map, say)."""
        try:
            yield
        except DataError as exc:
            raise DataError(f"frame {self.state.frame}, stage {name}: {exc} (run folder {self.run_dir} keeps "
                            "the frames before it)") from None

    def _event(self, text: str, level: int = logging.INFO) -> None:
        log.log(level, text)
        self.state.events.append(text)
        self.recorder.event(text)

    def finish(self) -> dict:
        """Close the recording and write the final map, trajectory and metrics.json; returns the metrics."""
        self.recorder.close()
        save_map(self.mapper.map, self.run_dir / run_folder.MAP, extras=self.cfg.output.ply_extras,
                 columns=self.selector.columns)
        write_trajectory_csv(self.run_dir / run_folder.TRAJECTORY, self.flight.log.columns())
        if self.dataset is not None:
            self.dataset.close(self.flight.log.columns())
        final = self.evaluation.evaluate(self.mapper)
        return outputs.write_metrics(self.run_dir, self.cfg, self.state, final, len(self.mapper.map),
                                     self.mapper.pruned, self.flight.time, len(self.flight.log.events))

    def _save_checkpoint(self) -> None:
        """The state of every component after this frame, as arrays and JSON (flightrecon.checkpoint)."""
        save_checkpoint(self.run_dir / run_folder.CHECKPOINT,
                        {"flight": self.flight.get_state(), "mapper": self.mapper.get_state(),
                         "planner": self.planner.get_state(), "selector": self.selector.get_state(),
                         "mission": self.state.to_checkpoint()})

    def _load_checkpoint(self, path: Path) -> None:
        state = load_checkpoint(path)
        self.flight.set_state(state["flight"])
        self.mapper.set_state(state["mapper"])  # the selector's columns come back with the map
        self.planner.set_state(state["planner"])
        self.selector.set_state(state["selector"])
        self.state = MissionState.from_checkpoint(state["mission"], self.state.coverage)
