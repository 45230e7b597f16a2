"""The fixed-rate flight cycle: control at `sim.control_rate_hz`, physics at `sim.physics_dt`.

Each control step reads the simulated state (the truth everything downstream uses), samples the
reference, runs the SE(3) controller and the mixer, holds the motor commands for the physics
substeps, then records one log row (state, reference, commands, rotor thrusts, clearance) and any
new contact with the scene. A diverged state stops the flight with `FlightDiverged`, whose `log`
(and `Flight.log`) keep everything recorded up to it; with `stop_on_contact` set (callers set it
from sim.on_contact once the drone is airborne: it starts resting on the floor), a new contact stops
it with `FlightContact`. `wait_until_arrived` holds the last reference
until position, yaw and speed have stayed inside their tolerances for the settle time, so images are
taken at rest. `estimated_camera_pose` adds the configured pose noise (what a mapper would get from
a state estimator); `camera_pose` is the exact simulated pose.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from flightrecon.config import ScenarioConfig
from flightrecon.control.mixer import Mixer
from flightrecon.control.reference_paths import MinJerkMove, wrap_angle
from flightrecon.control.se3 import SE3Controller
from flightrecon.control.trajectory import FlatState, Hold, Trajectory
from flightrecon.errors import ConfigError
from flightrecon.sim.quadrotor import DroneHandle, DroneState
from flightrecon.sim.safety import (ClearanceMonitor, ContactEvent, ContactMonitor, FlightContact, FlightDiverged,
                                    divergence_reason)

COLUMNS = ("t", "x", "y", "z", "qw", "qx", "qy", "qz", "vx", "vy", "vz", "wx", "wy", "wz",
           "ref_x", "ref_y", "ref_z", "ref_vx", "ref_vy", "ref_vz", "ref_yaw",
           "cmd0", "cmd1", "cmd2", "cmd3", "thrust0", "thrust1", "thrust2", "thrust3", "clearance")
_COL = {name: i for i, name in enumerate(COLUMNS)}
_BAD_STATE_WARNINGS = (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                       mujoco.mjtWarning.mjWARN_BADQACC)


class FlightLog:
    """Time series of one flight (one row per control step, `COLUMNS`) and its contact events."""

    def __init__(self) -> None:
        self._rows: list[list[float]] = []
        self._cache: np.ndarray | None = None
        self.events: list[ContactEvent] = []
        self.notes: list[str] = []

    def append(self, row: list[float]) -> None:
        self._rows.append(row)
        self._cache = None

    def __len__(self) -> int:
        return len(self._rows)

    @property
    def array(self) -> np.ndarray:
        if self._cache is None:
            self._cache = np.array(self._rows).reshape(-1, len(COLUMNS))
        return self._cache

    def __getitem__(self, name: str) -> np.ndarray:
        return self.array[:, _COL[name]]

    def block(self, *names: str) -> np.ndarray:
        return self.array[:, [_COL[n] for n in names]]

    @property
    def positions(self) -> np.ndarray:
        return self.block("x", "y", "z")

    @property
    def reference_positions(self) -> np.ndarray:
        return self.block("ref_x", "ref_y", "ref_z")

    def tracking_rms(self) -> float:
        """RMS of the 3D position error against the reference."""
        e = self.positions - self.reference_positions
        return float(np.sqrt(np.mean(np.sum(e * e, axis=1)))) if len(self) else 0.0

    def columns(self) -> dict[str, np.ndarray]:
        return {name: self.array[:, i] for i, name in enumerate(COLUMNS)}

    def get_state(self) -> dict:
        """The rows, contact events and notes as plain state (flightrecon.checkpoint)."""
        return {"rows": self.array.copy(), "events": [dataclasses.asdict(e) for e in self.events],
                "notes": list(self.notes)}

    def set_state(self, state: dict) -> None:
        self._rows = np.asarray(state["rows"], np.float64).tolist()
        self._cache = None
        self.events = [ContactEvent(**{**e, "position": tuple(e["position"])}) for e in state["events"]]
        self.notes = list(state["notes"])

    def truncate(self, rows: int, events: int, notes: int) -> None:
        """Drop what was appended after the log held `rows` rows, `events` events and `notes` notes."""
        del self._rows[rows:], self.events[events:], self.notes[notes:]
        self._cache = None

    def slice_from(self, start: int) -> "FlightLog":
        """The rows from `start` on, with the contacts that began in them (a step's contacts carry
        the time after it, which is the next row's)."""
        out = FlightLog()
        out._rows = self._rows[start:]
        if out._rows:
            out.events = [e for e in self.events if e.time > out._rows[0][0]]
        return out


class Flight:
    """Flies a drone of a compiled MuJoCo world along trajectories in the fixed-rate cycle."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, cfg: ScenarioConfig,
                 clearance: ClearanceMonitor | None = None) -> None:
        self.model, self.data, self.cfg = model, data, cfg
        self.drone = DroneHandle(model)
        substeps = 1.0 / (cfg.sim.control_rate_hz * cfg.sim.physics_dt)
        if abs(substeps - round(substeps)) > 1e-6 or round(substeps) < 1:
            raise ConfigError(f"config key 'sim.control_rate_hz': {cfg.sim.control_rate_hz} Hz is not a whole "
                              f"fraction of the physics rate 1/sim.physics_dt = {1 / cfg.sim.physics_dt:g} Hz")
        self.substeps = int(round(substeps))
        model.opt.timestep = cfg.sim.physics_dt
        self.control_dt = self.substeps * cfg.sim.physics_dt
        g = -float(model.opt.gravity[2])
        self.controller = SE3Controller.from_config(cfg, self.drone.mass, self.drone.inertia,
                                                    self.drone.max_thrust, self.drone.linear_drag, g)
        self.mixer = Mixer(self.drone.rotor_positions, self.drone.spin_sign, self.drone.yaw_torque_coeff,
                           self.drone.max_thrust)
        self.clearance = clearance
        self.contacts = ContactMonitor(model, self.drone.geom_ids)
        self.stop_on_contact = False  # raise FlightContact at a new contact with the scene
        self.log = FlightLog()
        self.last_reference: FlatState | None = None
        self._rng = np.random.default_rng([cfg.seed, 7919])
        self._watcher: Callable[[], None] | None = None  # `watch`: called every `_watch_period` s of flight
        self._watch_period = 0.0
        self._next_watch = math.inf
        self._bad_warnings_seen = self._bad_state_warnings()

    def _bad_state_warnings(self) -> int:
        w = self.data.warning
        return sum(int(w[i].number) for i in _BAD_STATE_WARNINGS)

    @classmethod
    def from_world(cls, world, cfg: ScenarioConfig, clearance: ClearanceMonitor | None = None) -> "Flight":
        return cls(world.model, world.data, cfg, clearance)

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> DroneState:
        return self.drone.state(self.data)

    @property
    def time(self) -> float:
        return float(self.data.time)

    def start(self, position: np.ndarray, yaw: float = 0.0) -> None:
        """Put the drone at rest at `position` (hover thrust already spun up) and hold there."""
        self.drone.set_pose(self.model, self.data, np.asarray(position, float), yaw)
        self.last_reference = Hold(np.asarray(position, float), yaw).sample(0.0)

    # ------------------------------------------------------------------ cycle
    def step(self, ref: FlatState) -> None:
        """One control period: control from the current state, physics substeps, log and checks."""
        p, q, v, w, R = self.drone.read(self.data)
        thrust, torque, _ = self.controller.compute_floats(p, v, R, w, ref)
        cmd = self.mixer.mix(thrust, torque)
        clearance = self.clearance(np.array(p)) if self.clearance is not None else math.nan
        row = [self.data.time, *p, *q, *v, *w, *ref.position.tolist(), *ref.velocity.tolist(), ref.yaw,
               *cmd.tolist(), *self.drone.motor_thrusts(self.data).tolist(), clearance]
        self.log.append(row)
        reason = divergence_reason(row[1:14], R[8], self.cfg.sim.divergence_tilt_deg)
        if reason is not None:
            self._diverged(row[0], reason)
        self.drone.set_motor_commands(self.data, cmd)
        mujoco.mj_step(self.model, self.data, self.substeps)
        seen, self._bad_warnings_seen = self._bad_warnings_seen, self._bad_state_warnings()
        if self._bad_warnings_seen > seen:  # (a data reset elsewhere lowers the count: not divergence)
            # MuJoCo replaces a NaN/inf state by its initial one and only warns: that is divergence.
            self._diverged(row[0], "the physics produced NaN or inf and MuJoCo reset the state")
        self.last_reference = ref
        events = self.contacts.update(self.data)
        if events:
            self.log.events.extend(events)
            if self.stop_on_contact:
                raise FlightContact(f"the drone touched the scene: {events[0].describe()}", events[0])
        if self._watcher is not None and self.data.time >= self._next_watch - 1e-9:
            self._next_watch += self._watch_period
            self._watcher()

    def watch(self, callback: Callable[[], None] | None, period: float) -> None:
        """Call `callback` every `period` s of simulated time while flying (never while rehearsing):
        what the camera streams between captures. None: stop."""
        self._watcher, self._watch_period = callback, float(period)
        self._next_watch = self.time + self._watch_period if callback is not None else math.inf

    def _diverged(self, t: float, reason: str) -> None:
        msg = f"flight diverged at t={t:.3f}s: {reason}; the log keeps {len(self.log)} steps"
        self.log.notes.append(msg)
        raise FlightDiverged(msg, self.log)

    def fly(self, trajectory: Trajectory, extra_time: float = 0.0) -> FlightLog:
        """Track `trajectory` from its start for its duration (+ `extra_time` holding its end)."""
        start = len(self.log)
        n = int(math.ceil((trajectory.duration + extra_time) / self.control_dt - 1e-9))
        for k in range(n):
            self.step(trajectory.sample(k * self.control_dt))
        self.last_reference = trajectory.sample(trajectory.duration)
        return self.log.slice_from(start)

    def hover(self, seconds: float) -> FlightLog:
        """Hold the last reference for `seconds`."""
        return self.fly(Hold(self.last_reference.position, self.last_reference.yaw, seconds))

    def go_to(self, position: np.ndarray, yaw: float) -> FlightLog:
        """Rest-to-rest straight move at the configured planner limits (take-off, scripted flights)."""
        p = self.cfg.planner
        move = MinJerkMove.within_limits(self.last_reference.position, position, self.last_reference.yaw, yaw,
                                         p.max_vel, p.max_acc, p.max_jerk, math.radians(p.max_yaw_rate_deg),
                                         math.radians(p.max_yaw_acc_deg))
        return self.fly(move)

    def rehearse(self, trajectory: Trajectory) -> np.ndarray:
        """Positions (N, 3) the drone would pass tracking `trajectory` and settling at its end (`fly`,
        then `wait_until_arrived`), simulated from the current state and then undone. The tracking
        error shows here, which the planned reference does not; the simulation is deterministic, so
        the flight that follows the rehearsal is the one rehearsed, and one that would diverge raises
        FlightDiverged now, as flying it would (the state is restored either way)."""
        kind = mujoco.mjtState.mjSTATE_INTEGRATION
        sim = np.empty(mujoco.mj_stateSize(self.model, kind))
        mujoco.mj_getState(self.model, self.data, sim, kind)
        kept = (self.last_reference, self._rng.bit_generator.state, set(self.contacts.active), self.stop_on_contact,
                self._watcher)
        sizes = (len(self.log), len(self.log.events), len(self.log.notes))
        self.stop_on_contact, self._watcher = False, None
        try:
            self.fly(trajectory)
            self.wait_until_arrived()
            return self.log.positions[sizes[0]:].copy()
        finally:
            mujoco.mj_setState(self.model, self.data, sim, kind)
            mujoco.mj_forward(self.model, self.data)
            self.last_reference, rng, self.contacts.active, self.stop_on_contact, self._watcher = kept
            self._rng.bit_generator.state = rng
            self.log.truncate(*sizes)
            self._bad_warnings_seen = self._bad_state_warnings()

    def arrived(self, target: FlatState) -> bool:
        """Position, yaw and speed inside the control tolerances right now."""
        c = self.cfg.control
        s = self.drone.state(self.data)
        return (float(np.linalg.norm(s.position - target.position)) < c.arrive_pos_tol
                and abs(wrap_angle(s.yaw - target.yaw)) < math.radians(c.arrive_yaw_tol_deg)
                and float(np.linalg.norm(s.velocity)) < c.arrive_speed_tol)

    def wait_until_arrived(self, target: FlatState | None = None, timeout: float | None = None) -> bool:
        """Hold `target` (default: the end of the last trajectory) until the drone has stayed inside
        the tolerances for `control.settle_time`; False (and a log note) after the timeout."""
        c = self.cfg.control
        target = target if target is not None else self.last_reference
        hold = Hold(target.position, target.yaw).sample(0.0)
        timeout = c.arrive_timeout if timeout is None else timeout
        settled = 0.0
        waited = 0.0
        while waited <= timeout + 1e-9:
            if self.arrived(hold):
                if settled >= c.settle_time - 1e-9:
                    return True
                settled += self.control_dt
            else:
                settled = 0.0
            self.step(hold)
            waited += self.control_dt
        self.log.notes.append(f"t={self.time:.2f}s: did not settle at {np.round(target.position, 3).tolist()} "
                              f"within {timeout:g}s")
        return False

    # ------------------------------------------------------------------ checkpoints
    def get_state(self) -> dict:
        """Everything needed to continue this flight bit-exactly, as plain state: MuJoCo's integration
        state (incl. warm start and motor activations), the last reference, the noise RNG, the log and
        the contacts under way. The controller and mixer are rebuilt from the config."""
        kind = mujoco.mjtState.mjSTATE_INTEGRATION
        sim = np.empty(mujoco.mj_stateSize(self.model, kind))
        mujoco.mj_getState(self.model, self.data, sim, kind)
        ref = None if self.last_reference is None else dataclasses.asdict(self.last_reference)
        return {"sim": sim, "last_reference": ref, "rng": self._rng.bit_generator.state,
                "log": self.log.get_state(), "contacts": sorted(list(pair) for pair in self.contacts.active),
                "next_watch": self._next_watch}

    def set_state(self, state: dict) -> None:
        """Restore a `get_state()` snapshot into this flight's (identically built) world."""
        mujoco.mj_setState(self.model, self.data, state["sim"], mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_forward(self.model, self.data)
        ref = state["last_reference"]
        self.last_reference = None if ref is None else FlatState(**ref)
        self._rng.bit_generator.state = state["rng"]
        self.log = FlightLog()
        self.log.set_state(state["log"])
        self.contacts.active = {(int(a), int(b)) for a, b in state["contacts"]}
        self._next_watch = float(state.get("next_watch", math.inf))

    # ------------------------------------------------------------------ camera
    def sync(self) -> None:
        """Recompute kinematics for the current state, so camera poses and renders match qpos."""
        mujoco.mj_forward(self.model, self.data)

    def camera_pose(self) -> np.ndarray:
        """Exact T_wc (OpenCV) of drone_cam at the current simulated state."""
        self.sync()
        return self.drone.camera_pose(self.data)

    def capture(self, camera) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """RGB-D from drone_cam at the current state with `camera` (a sim.camera.RGBDCamera built from
        the same camera config): (rgb, depth, T_wc as given to mapping (noisy if configured), T_wc true)."""
        self.sync()
        rgb, depth, T_wc = camera.render_named("drone_cam")
        return rgb, depth, self.estimated_camera_pose(T_wc), T_wc

    def capture_depth(self, camera, reduce: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Depth alone from drone_cam at 1/`reduce` of `camera`'s size (K: camera.intrinsics_at(reduce)),
        and T_wc with the same pose noise as `capture`."""
        self.sync()
        _, depth, T_wc = camera.render_named("drone_cam", reduce)
        return depth, self.estimated_camera_pose(T_wc)

    def estimated_camera_pose(self, T_wc: np.ndarray | None = None) -> np.ndarray:
        """T_wc with the configured pose noise (sim.pose_noise_pos_m, sim.pose_noise_rot_deg)."""
        T = (self.camera_pose() if T_wc is None else np.asarray(T_wc, float)).copy()
        sp, sr = self.cfg.sim.pose_noise_pos_m, math.radians(self.cfg.sim.pose_noise_rot_deg)
        if sp > 0:
            T[:3, 3] += self._rng.normal(0.0, sp, 3)
        if sr > 0:
            T[:3, :3] = T[:3, :3] @ Rotation.from_rotvec(self._rng.normal(0.0, sr, 3)).as_matrix()
        return T
