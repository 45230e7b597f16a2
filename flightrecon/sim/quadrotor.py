"""The quadrotor plant: models/quadrotor.xml with its numbers set from the scenario config.

`add_quadrotor` puts the drone into a world spec; `DroneHandle` reads and writes its state in a
compiled model. The drone's qpos is laid out like a free joint, [x y z qw qx qy qz] in the world
frame, and its qvel as [world linear velocity, body angular velocity]; it is made of three world
slides (which carry the linear drag as joint damping, integrated implicitly by MuJoCo) and a ball
joint, so rotation is not damped. Rotor i pushes along body z at its arm's end and twists the body
about z by `spin_sign[i] * yaw_torque_coeff` newton-meters per newton; each motor follows its
command through a first-order lag (MuJoCo's filter actuator dynamics).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from flightrecon.config import ScenarioConfig
from flightrecon.errors import ConfigError
from flightrecon.resources import resource
from flightrecon.geometry import (R_CV_FROM_MJ, body_to_camera_rotation, mujoco_camera_to_opencv,
                                  rot_z, rotmat_to_quat, vfov_deg)

MODEL_PATH = resource("models") / "quadrotor.xml"
BODY = "drone"
CAMERA = "drone_cam"
# Rotor layout of the X frame: front-left, back-left, back-right, front-right (body x fwd, y left).
ROTOR_DIRECTIONS = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]]) / math.sqrt(2.0)
SPIN_SIGN = np.array([1.0, -1.0, 1.0, -1.0])
_HULL_HALF_HEIGHT = 0.03
_ROTOR_HEIGHT = 0.02


def rotor_positions(arm_length: float) -> np.ndarray:
    """(4, 3) rotor hubs in the body frame."""
    xy = ROTOR_DIRECTIONS * arm_length
    return np.column_stack([xy, np.full(4, _ROTOR_HEIGHT)])


def camera_offset(arm_length: float) -> np.ndarray:
    """Mounting point of the camera in the body frame: just ahead of the hull's front face."""
    return np.array([0.35 * arm_length + 0.01, 0.0, 0.0])


def add_quadrotor(spec: mujoco.MjSpec, cfg: ScenarioConfig) -> None:
    """Add the body "drone" (joints, collision frame, four motors, camera "drone_cam") to `spec`."""
    d = cfg.drone
    prop_radius = d.body_radius - d.arm_length
    if prop_radius < 0.02:
        raise ConfigError(f"config key 'drone.body_radius': {d.body_radius} leaves no room for the "
                          f"propellers beyond drone.arm_length = {d.arm_length} (needs >= 0.02 m more)")
    if len(d.inertia) != 3 or not all(isinstance(v, (int, float)) and v > 0 for v in d.inertia):
        raise ConfigError(f"config key 'drone.inertia': expected three positive numbers, got {d.inertia!r}")
    child = mujoco.MjSpec.from_file(str(MODEL_PATH))
    body = child.body("_body")
    body.pos = [0.0, 0.0, 0.0]  # slides measure from the world origin: qpos[:3] is the position
    body.mass = d.mass
    body.inertia = [float(v) for v in d.inertia]
    for axis in "xyz":
        child.joint(f"_{axis}").damping = [d.linear_drag, 0.0, 0.0]
    L = d.arm_length
    child.geom("_hull").size = [0.35 * L, 0.3 * L, _HULL_HALF_HEIGHT]
    hubs = rotor_positions(L)
    for arm, (a, b) in (("a", (2, 0)), ("b", (1, 3))):
        child.geom(f"_arm_{arm}").fromto = np.concatenate([hubs[a] * [1, 1, 0], hubs[b] * [1, 1, 0]])
    for i in range(4):
        child.geom(f"_prop{i}").pos = hubs[i]
        child.geom(f"_prop{i}").size = [prop_radius, 0.006, 0.0]
        child.site(f"_rotor{i}").pos = hubs[i]
        act = child.actuator(f"_motor{i}")
        act.ctrlrange = [0.0, d.max_motor_thrust]
        act.gear = [0.0, 0.0, 1.0, 0.0, 0.0, SPIN_SIGN[i] * d.yaw_torque_coeff]
        if d.motor_time_constant > 0:
            act.dyntype = mujoco.mjtDyn.mjDYN_FILTER
            act.dynprm[0] = d.motor_time_constant
        else:
            act.dyntype = mujoco.mjtDyn.mjDYN_NONE
    cam = child.camera("_cam")
    cam.pos = camera_offset(L)
    cam.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT
    cam.quat = rotmat_to_quat(body_to_camera_rotation(cfg.camera.pitch_deg) @ R_CV_FROM_MJ)
    cam.fovy = vfov_deg(cfg.camera.width, cfg.camera.height, cfg.camera.hfov_deg)
    cam.resolution = [cfg.camera.width, cfg.camera.height]
    spec.worldbody.add_frame().attach_body(body, BODY, "").name = BODY


@dataclass(frozen=True)
class DroneState:
    position: np.ndarray  # (3,) world
    quat: np.ndarray  # (4,) wxyz, body-to-world
    velocity: np.ndarray  # (3,) world
    omega: np.ndarray  # (3,) body angular velocity
    R: np.ndarray  # (3, 3) body-to-world

    @property
    def yaw(self) -> float:
        return math.atan2(self.R[1, 0], self.R[0, 0])

    @property
    def tilt(self) -> float:
        """Angle between body z and world z (rad)."""
        return math.acos(max(-1.0, min(1.0, self.R[2, 2])))


class DroneHandle:
    """Indices of the drone in a compiled model, and state access on its data."""

    def __init__(self, model: mujoco.MjModel) -> None:
        try:
            self.body_id = model.body(BODY).id
            jx = model.joint("drone_x")
            self.motor_ids = np.array([model.actuator(f"drone_motor{i}").id for i in range(4)])
            self.camera_id = model.camera(CAMERA).id
        except KeyError as exc:
            raise ConfigError(f"the world has no quadrotor from add_quadrotor ({exc})") from None
        self.qpos_adr = int(jx.qposadr[0])
        self.qvel_adr = int(jx.dofadr[0])
        self.act_adr = np.array([model.actuator_actadr[i] for i in self.motor_ids])
        start, num = model.body_geomadr[self.body_id], model.body_geomnum[self.body_id]
        self.geom_ids = np.arange(start, start + num)
        self.mass = float(model.body_mass[self.body_id])
        self.inertia = model.body_inertia[self.body_id].copy()
        self.max_thrust = float(model.actuator_ctrlrange[self.motor_ids[0], 1])
        self.yaw_torque_coeff = abs(float(model.actuator_gear[self.motor_ids[0], 5]))
        self.linear_drag = float(model.dof_damping[self.qvel_adr])
        sites = model.actuator_trnid[self.motor_ids, 0]
        self.rotor_positions = model.site_pos[sites].copy()
        self.spin_sign = np.sign(model.actuator_gear[self.motor_ids, 5])
        self.camera_offset = model.cam_pos[self.camera_id].copy()

    def read(self, data: mujoco.MjData) -> tuple[list, list, list, list, list]:
        """Position, unit quaternion (wxyz), velocity, body rates and R (row-major, 9) as plain floats
        (the flight cycle's fast path; `state` wraps it in arrays)."""
        a, b = self.qpos_adr, self.qvel_adr
        x, y, z, qw, qx, qy, qz = data.qpos[a:a + 7].tolist()
        n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        if n > 0:
            qw, qx, qy, qz = qw / n, qx / n, qy / n, qz / n
        qv = data.qvel[b:b + 6].tolist()
        R = [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy),
             2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx),
             2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)]
        return [x, y, z], [qw, qx, qy, qz], qv[:3], qv[3:], R

    def state(self, data: mujoco.MjData) -> DroneState:
        p, q, v, w, R = self.read(data)
        return DroneState(np.array(p), np.array(q), np.array(v), np.array(w), np.array(R).reshape(3, 3))

    def set_pose(self, model: mujoco.MjModel, data: mujoco.MjData, position: np.ndarray, yaw: float = 0.0) -> None:
        """Place the drone at rest, level, with motors spun up to hover thrust; recomputes kinematics."""
        a = self.qpos_adr
        data.qpos[a:a + 3] = position
        data.qpos[a + 3:a + 7] = rotmat_to_quat(rot_z(yaw))
        data.qvel[self.qvel_adr:self.qvel_adr + 6] = 0.0
        hover = self.mass * -model.opt.gravity[2] / 4.0
        data.ctrl[self.motor_ids] = hover
        if model.na:
            data.act[self.act_adr[self.act_adr >= 0]] = hover
        mujoco.mj_forward(model, data)

    def set_motor_commands(self, data: mujoco.MjData, thrusts: np.ndarray) -> None:
        data.ctrl[self.motor_ids] = thrusts

    def motor_thrusts(self, data: mujoco.MjData) -> np.ndarray:
        """The rotors' current (lagged) thrusts."""
        return data.actuator_force[self.motor_ids].copy()

    def camera_pose(self, data: mujoco.MjData) -> np.ndarray:
        """T_wc (OpenCV axes) of drone_cam from the data's current kinematics."""
        return mujoco_camera_to_opencv(data.cam_xpos[self.camera_id], data.cam_xmat[self.camera_id])
