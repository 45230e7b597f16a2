"""Feasibility of a whole candidate library: the set the view selector scores.

On the online map, occupied space must stay beyond body radius + safety margin and unknown space
beyond the body radius (both through one field, see OccupancyMap.distance_field).

For every candidate the check returns feasible or the first reason it is not:
out_of_bounds (outside the workspace box), in_obstacle / unknown_space (the target voxel), clearance
(the target, or every trajectory found, comes closer than body radius + safety margin),
no_path (OMPL found none in its time limit), limits (velocity, acceleration, jerk, yaw rate or
tilt exceeded), too_long (duration over the maximum).

Straight legs are tried first for all candidates at once; only the ones whose straight trajectory
loses clearance go to OMPL, and only when the connected components of the clearance grid (built
once per check) join start and goal. Every trajectory is sampled densely (a quarter voxel of travel between
samples) and its clearance required with a Lipschitz margin, so it holds between samples too.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from flightrecon.config import ScenarioConfig
from flightrecon.control.trajectory import FlatState
from flightrecon.planning.distance_field import DistanceField
from flightrecon.planning.library import ViewpointLibrary, in_bounds, load_library
from flightrecon.planning.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyMap
from flightrecon.planning.paths import ReachableSpace, escape_point, plan_path, search_margin, seed_ompl
from flightrecon.planning.timing import JerkTrajectory, Limits, evaluate_batch, time_path, unwrap_yaws

REASONS = ("feasible", "out_of_bounds", "in_obstacle", "unknown_space", "clearance", "no_path",
           "limits", "too_long")
GRAVITY = 9.81


@dataclass
class CandidateResult:
    """Outcome for one candidate view; `trajectory` is set only when feasible."""

    position: np.ndarray
    yaw: float
    reason: str
    trajectory: JerkTrajectory | None = None
    duration: float = math.nan
    length: float = math.nan
    used_ompl: bool = False
    min_clearance: float = math.nan

    @property
    def feasible(self) -> bool:
        return self.reason == "feasible"


@dataclass(frozen=True)
class PlanningSettings:
    """What the checks need from the scenario config, resolved to SI units."""

    limits: Limits
    required_clearance: float
    body_radius: float
    max_tilt: float
    max_duration: float
    ompl_time_limit: float
    ompl_iterations: int

    @classmethod
    def from_config(cls, cfg: ScenarioConfig) -> "PlanningSettings":
        p, d = cfg.planner, cfg.drone
        limits = Limits(p.max_vel, p.max_acc, p.max_jerk, math.radians(p.max_yaw_rate_deg),
                        math.radians(p.max_yaw_acc_deg), math.radians(p.max_yaw_jerk_deg))
        return cls(limits, cfg.required_clearance, d.body_radius, math.radians(d.max_tilt_deg),
                   p.max_duration, p.ompl_time_limit, p.ompl_iterations)


@dataclass
class PlanningTimes:
    """Seconds spent per stage in the last library check (for the benchmark and study)."""

    total: float = 0.0
    straight: float = 0.0
    ompl: float = 0.0
    n_ompl: int = 0


def required_at(points: np.ndarray, field: DistanceField, settings: PlanningSettings,
                start: np.ndarray | None = None) -> np.ndarray:
    """Clearance required at each point (N, 3) of a path from `start`: the settings' everywhere,
    except near a start that is itself below the search's clearance, where it is the start's own
    clearance less half a voxel (the drone may leave, not come closer)."""
    req = np.full(len(points), settings.required_clearance)
    if start is not None:
        d0 = float(field.distance(np.asarray(start, float)[None])[0])
        if d0 < settings.required_clearance + search_margin(field):
            radius = max(settings.required_clearance - d0, 0.0) + field.voxel_size
            near = np.linalg.norm(points - start, axis=1) < radius
            req[near] = d0 - field.voxel_size / 2
    return req


def check_trajectories(trajs: list[JerkTrajectory], field: DistanceField, settings: PlanningSettings,
                       start: np.ndarray | None = None) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Dense check of many trajectories at once -> (reason per trajectory, min clearance, length).

    Samples are spaced so no axis moves more than a quarter voxel between them; the clearance
    required at samples adds sqrt(3)/2 of the largest sample spacing (the field's Lipschitz bound).
    A drone that starts below the search's clearance (after a tracking error, or hovering just past
    the requirement, where its own start sample would fail) may leave: near `start` the requirement
    drops to its current clearance less half a voxel (it may not get closer)."""
    lim = settings.limits
    if not trajs:
        return [], np.zeros(0), np.zeros(0)
    dt = (field.voxel_size / 4) / max(lim.vel, 1e-9)
    times = [np.linspace(0.0, tr.duration, max(int(math.ceil(tr.duration / dt)), 1) + 1) for tr in trajs]
    pos, vel, acc, jerk = evaluate_batch(trajs, times)
    who = np.repeat(np.arange(len(trajs)), [len(t) for t in times])
    clear = field.distance(pos[:, :3])
    step = np.zeros(len(pos))
    same = who[1:] == who[:-1]
    step[1:][same] = np.linalg.norm(np.diff(pos[:, :3], axis=0), axis=1)[same]
    n = len(trajs)
    min_clear = np.full(n, np.inf)
    np.minimum.at(min_clear, who, clear)
    max_step = np.zeros(n)
    np.maximum.at(max_step, who, step)
    length = np.bincount(who, weights=step, minlength=n)
    tol = 1e-6
    over = ((np.abs(vel[:, :3]) > lim.vel + tol).any(1) | (np.abs(acc[:, :3]) > lim.acc + tol).any(1)
            | (np.abs(jerk[:, :3]) > lim.jerk + tol).any(1) | (np.abs(vel[:, 3]) > lim.yaw_rate + tol)
            | (np.abs(acc[:, 3]) > lim.yaw_acc + tol) | (np.abs(jerk[:, 3]) > lim.yaw_jerk + tol))
    thrust_z = acc[:, 2] + GRAVITY
    tilt = np.arctan2(np.linalg.norm(acc[:, :2], axis=1), thrust_z)
    over |= (thrust_z <= 0) | (tilt > settings.max_tilt)
    bad_limits = np.bincount(who, weights=over.astype(float), minlength=n) > 0
    req = required_at(pos[:, :3], field, settings, start)
    short = clear < req + math.sqrt(3) * max_step[who] / 2
    bad_clear = np.bincount(who, weights=short.astype(float), minlength=n) > 0
    reasons = []
    for i, tr in enumerate(trajs):
        if bad_clear[i]:
            reasons.append("clearance")
        elif bad_limits[i]:
            reasons.append("limits")
        elif tr.duration > settings.max_duration:
            reasons.append("too_long")
        else:
            reasons.append("feasible")
    return reasons, min_clear, length


def check_candidates(start: FlatState, positions: np.ndarray, yaws: np.ndarray, field: DistanceField,
                     target_state: np.ndarray, workspace: np.ndarray, settings: PlanningSettings,
                     times: PlanningTimes | None = None) -> list[CandidateResult]:
    """Feasibility of every candidate (positions (N, 3), yaws (N,)) from the current flat state:
    targets screened, then straight legs for all together, then OMPL detours for those whose
    straight leg came too close to an obstacle.

    `target_state` (N,) holds each target's map state (FREE, OCCUPIED, UNKNOWN)."""
    t_all = time.perf_counter()
    times = times if times is not None else PlanningTimes()
    results = [CandidateResult(np.asarray(positions[i], float), float(yaws[i]), "") for i in range(len(positions))]
    d_target = field.distance(positions)
    need = required_at(positions, field, settings, np.asarray(start.position, float))
    todo = _screen_targets(results, in_bounds(positions, workspace), target_state, d_target < need)
    t0 = time.perf_counter()
    retry = _straight_legs(start, results, todo, field, settings)
    times.straight = time.perf_counter() - t0
    t0 = time.perf_counter()
    _detours(start, results, retry, d_target, field, workspace, settings, times)
    times.ompl = time.perf_counter() - t0
    times.total = time.perf_counter() - t_all
    return results


def _screen_targets(results: list[CandidateResult], inside: np.ndarray, target_state: np.ndarray,
                    too_close: np.ndarray) -> list[int]:
    """Give a reason to each candidate whose target itself is unusable (`too_close`: below the
    clearance required there, which near a tight start is the start's own); returns the others' indices."""
    todo = []
    for i, r in enumerate(results):
        if not inside[i]:
            r.reason = "out_of_bounds"
        elif target_state[i] == OCCUPIED:
            r.reason = "in_obstacle"
        elif target_state[i] == UNKNOWN:
            r.reason = "unknown_space"
        elif too_close[i]:
            r.reason = "clearance"
        else:
            todo.append(i)
    return todo


def _motion_start(start: FlatState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(position, [velocity, yaw rate], [acceleration, 0]) of the flat state, as time_path takes them."""
    return (np.asarray(start.position, float), np.array([*start.velocity, start.yaw_rate], float),
            np.array([*start.acceleration, 0.0], float))


def _straight_legs(start: FlatState, results: list[CandidateResult], todo: list[int], field: DistanceField,
                   settings: PlanningSettings) -> list[int]:
    """Time and check a straight leg to every candidate in `todo` (checked together); returns the
    indices whose leg failed only on clearance (worth a detour)."""
    p0, v0, a0 = _motion_start(start)
    trajs, ok_idx, retry = [], [], []
    for i in todo:
        yaw_path = unwrap_yaws(start.yaw, results[i].yaw, np.array([0.0, 1.0]))
        tr = time_path(np.stack([p0, results[i].position]), yaw_path, settings.limits, v0, a0)
        if tr is None:
            results[i].reason = "limits"
            continue
        trajs.append(tr)
        ok_idx.append(i)
    reasons, min_clear, length = check_trajectories(trajs, field, settings, p0)
    for i, tr, why, mc, ln in zip(ok_idx, trajs, reasons, min_clear, length):
        if why == "clearance":
            retry.append(i)
        else:
            _finish(results[i], tr, why, mc, ln, used_ompl=False)
    return retry


def _detours(start: FlatState, results: list[CandidateResult], retry: list[int], d_target: np.ndarray,
             field: DistanceField, workspace: np.ndarray, settings: PlanningSettings, times: PlanningTimes) -> None:
    """An OMPL path around the obstacles to each candidate in `retry`, timed and checked. A start
    too close for the search roots it at its escape point, reached by a first straight leg."""
    p0 = np.asarray(start.position, float)
    need = settings.required_clearance + search_margin(field)
    root = escape_point(field, p0, need, workspace)
    reach: ReachableSpace | None = None  # built for the step's first search, reused by the others
    for i in retry:
        r = results[i]
        if root is None or d_target[i] < need:
            r.reason = "clearance"  # too tight at either end to search a detour
            continue
        reach = reach or ReachableSpace(field, need)
        if not reach.may_connect(root, r.position):
            r.reason = "no_path"  # sealed off: no search could succeed
            continue
        times.n_ompl += 1
        path = plan_path(field, root, r.position, settings.required_clearance, workspace,
                         settings.ompl_time_limit, settings.ompl_iterations)
        if path is None:
            r.reason = "no_path"
            continue
        if not np.array_equal(root, p0):
            path = np.vstack([p0, path])
        _time_detour(start, r, path, field, settings)


def _time_detour(start: FlatState, r: CandidateResult, path: np.ndarray, field: DistanceField,
                 settings: PlanningSettings) -> None:
    """Time an OMPL path: flowing through its waypoints first, stopping at each (straight legs) if
    flowing cuts a corner."""
    p0, v0, a0 = _motion_start(start)
    seg_len = np.linalg.norm(np.diff(path, axis=0), axis=1)
    frac = np.concatenate([[0.0], np.cumsum(seg_len)]) / max(seg_len.sum(), 1e-9)
    yaw_path = unwrap_yaws(start.yaw, r.yaw, frac)
    why, tr, mc, ln = "clearance", None, math.nan, math.nan
    for stop in (False, True):
        cand = time_path(path, yaw_path, settings.limits, v0, a0, stop_at_waypoints=stop)
        if cand is None:
            why = "limits"
            continue
        (why,), (mc,), (ln,) = check_trajectories([cand], field, settings, p0)
        tr = cand
        if why == "feasible":
            break
    _finish(r, tr, why, mc, ln, used_ompl=True)


def _finish(r: CandidateResult, tr: JerkTrajectory | None, why: str, min_clear: float, length: float,
            used_ompl: bool) -> None:
    r.reason = why
    r.used_ompl = used_ompl
    r.min_clearance = float(min_clear)
    if tr is not None:
        r.duration = tr.duration
        r.length = float(length)
    if why == "feasible":
        r.trajectory = tr


class Planner:
    """Keeps the planning world (online occupancy map, or the ground-truth scene) and checks libraries.

    `workspace` (2, 3) is the box candidates must lie in; the map covers it plus a margin."""

    def __init__(self, cfg: ScenarioConfig, workspace: np.ndarray, scene_mesh=None,
                 start_position: np.ndarray | None = None):
        self.cfg = cfg
        self.settings = PlanningSettings.from_config(cfg)
        self.library: ViewpointLibrary = load_library(cfg.planner.library)
        self.workspace = np.asarray(workspace, float)
        pad = cfg.required_clearance + 2 * cfg.planner.voxel_size
        self.map_bounds = self.workspace + np.array([[-pad], [pad]])
        self.times = PlanningTimes()
        seed_ompl(cfg.seed)
        self.occupancy: OccupancyMap | None = None
        self._field: DistanceField | None = None
        if cfg.planner.use_ground_truth:
            if scene_mesh is None:
                raise ValueError("planner.use_ground_truth needs the scene mesh")
            seeds = None if start_position is None else np.asarray(start_position, float)[None]
            self._field = DistanceField.from_mesh(scene_mesh, cfg.planner.voxel_size, self.map_bounds,
                                                  free_seeds=seeds, signed=False)
        else:
            self.occupancy = OccupancyMap(self.map_bounds, cfg.planner.voxel_size, cfg.planner.free_range)
            if start_position is not None:
                self.mark_body_free(start_position)

    def get_state(self) -> dict:
        """The online occupancy map's evidence (None when planning on the ground truth, which the
        config rebuilds); the clearance field is derived from it. OMPL's seed is the caller's."""
        return {"occupancy": None if self.occupancy is None else self.occupancy.get_state()}

    def set_state(self, state: dict) -> None:
        """Continue from a `get_state()` snapshot of a planner built with the same config."""
        if (state["occupancy"] is None) != (self.occupancy is None):
            raise ValueError("planner state and planner disagree on planner.use_ground_truth")
        if self.occupancy is not None:
            self.occupancy.set_state(state["occupancy"])
            self._field = None

    def integrate(self, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray,
                  body_position: np.ndarray | None = None) -> None:
        """Add a depth frame to the online map (ignored when planning on the ground truth)."""
        if self.occupancy is None:
            return
        # the simulated camera returns 0 only where nothing lies within its far plane
        self.occupancy.integrate(depth, K, T_wc, no_return=self.cfg.camera.far)
        if body_position is not None:
            self.mark_body_free(body_position)
        r = self.cfg.planner.hover_free_radius
        if r > 0:
            # only the band of heights the drone's own clearance spans at the camera's height, and never
            # below the floor or above the top its body may reach: a level flight needs it; a climb or
            # a descent into the cones waits until they have been seen from further off (a table top
            # 0.48 m under the drone was flown into when the whole cone was assumed free)
            body, band = self.cfg.drone.body_radius, self.settings.required_clearance
            z = float(T_wc[2, 3])
            heights = (max(self.workspace[0, 2] - body, z - band), min(self.workspace[1, 2] + body, z + band))
            self.occupancy.mark_blind_free(T_wc, K, depth.shape[1], depth.shape[0], r, heights)
        self._field = None

    def mark_body_free(self, position: np.ndarray) -> None:
        """The never-seen space the drone's body fills where it is: free (its body proves it). What
        the camera has seen is never overridden."""
        if self.occupancy is None:
            return
        self.occupancy.mark_free_sphere(position, self.cfg.drone.body_radius)
        self._field = None

    @property
    def field(self) -> DistanceField:
        """Planning clearance: to the true scene, or min(d_occupied, d_unknown + safety margin)."""
        if self._field is None:
            self._field = self.occupancy.distance_field(unknown_offset=self.cfg.planner.safety_margin)
        return self._field

    def keeps_clearance(self, path: np.ndarray, start: np.ndarray) -> bool:
        """Whether a densely sampled path from `start` (the flight `Flight.rehearse` predicts, a
        control period between samples) keeps the clearance a planned trajectory must keep on the
        planning field, with the same Lipschitz margin for its sample spacing."""
        path = np.asarray(path, float).reshape(-1, 3)
        if not len(path):
            return True
        step = float(np.linalg.norm(np.diff(path, axis=0), axis=1).max()) if len(path) > 1 else 0.0
        req = required_at(path, self.field, self.settings, np.asarray(start, float))
        return bool(np.all(self.field.distance(path) >= req + math.sqrt(3) * step / 2))

    def target_states(self, positions: np.ndarray) -> np.ndarray:
        if self.occupancy is not None:
            return self.occupancy.state(positions)
        return np.where(self.field.distance(positions) > 0, FREE, OCCUPIED).astype(np.int8)

    def check(self, start: FlatState, positions: np.ndarray, yaws: np.ndarray) -> list[CandidateResult]:
        """Feasibility of explicit candidate poses from the current flat state."""
        self.times = PlanningTimes()
        pos = np.asarray(positions, float).reshape(-1, 3)
        yaw = np.asarray(yaws, float).reshape(-1)
        if len(yaw) != len(pos):
            raise ValueError(f"{len(pos)} candidate positions but {len(yaw)} yaws")
        return check_candidates(start, pos, yaw, self.field, self.target_states(pos), self.workspace,
                                self.settings, self.times)

    def check_library(self, start: FlatState) -> list[CandidateResult]:
        """Feasibility of the whole library around the current position and heading."""
        positions, yaws = self.library.poses(start.position, start.yaw)
        return self.check(start, positions, yaws)
