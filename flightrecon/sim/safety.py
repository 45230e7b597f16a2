"""Flight safety monitors: clearance to the scene, contacts with it, and divergence of the state.

Clearance is the exact distance from the drone's center to the scene's triangles
(scene.surface_distance) minus the radius of the sphere that encloses the frame and rotors, so it is
the distance from the drone's body to the nearest surface (negative: the sphere overlaps the scene).
Contacts are MuJoCo's own contacts between a drone geom and any other geom: one event when a pair
starts touching, not one per step; a flight told to stop on contact (sim.on_contact) raises
`FlightContact` at the first one. Divergence (a non-finite state or a tilt beyond the limit)
raises `FlightDiverged`, which carries the log recorded so far.

The safety margin is a contract: the planner keeps drone.body_radius + planner.safety_margin from
the scene, so a flight whose clearance falls below planner.safety_margin broke it. `MarginRecord`
says where (frames.csv's per-frame lowest clearance, take-off excluded), for metrics.json, the
flight's summary and a sweep's report alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from flightrecon.errors import FlightReconError
from flightrecon.scene.surface_distance import SurfaceDistance


class FlightDiverged(FlightReconError):
    """The simulated drone left the envelope the controller can recover from; `log` keeps the record."""

    def __init__(self, message: str, log=None) -> None:
        super().__init__(message)
        self.log = log


class ClearanceMonitor:
    """Distance (m) from the drone's enclosing sphere to the nearest surface of `mesh` (the scene)."""

    def __init__(self, mesh, body_radius: float) -> None:
        self.surface = SurfaceDistance(mesh)
        self.body_radius = float(body_radius)

    def __call__(self, position: np.ndarray) -> float:
        return float(self.surface.distance(np.asarray(position, float).reshape(1, 3))[0]) - self.body_radius


@dataclass(frozen=True)
class MarginRecord:
    """A flight's lowest clearance after take-off and the frames whose flight went below the margin."""

    margin: float  # planner.safety_margin (m)
    lowest: float  # m; NaN when no frame flew
    lowest_frame: int | None
    breach_frames: tuple[int, ...]

    @classmethod
    def of(cls, frames: list[int], min_clearance: list[float], margin: float) -> "MarginRecord":
        """From frames.csv's `frame` and `min_clearance` columns (NaN: the frame did not fly)."""
        c = np.asarray(min_clearance, float)
        flown = np.flatnonzero(np.isfinite(c))
        if not len(flown):
            return cls(float(margin), math.nan, None, ())
        worst = int(flown[np.argmin(c[flown])])
        breach = tuple(int(frames[i]) for i in flown if c[i] < margin)
        return cls(float(margin), float(c[worst]), int(frames[worst]), breach)

    @property
    def kept(self) -> bool:
        return not self.breach_frames

    def to_dict(self) -> dict:
        return {"safety_margin_m": self.margin, "min_clearance_m": None if math.isnan(self.lowest) else self.lowest,
                "min_clearance_frame": self.lowest_frame, "margin_breach_frames": list(self.breach_frames)}

    def warning(self) -> str:
        """The line that keeps a flight inside its own margin from reading like a safe one ("" when kept)."""
        if self.kept:
            return ""
        n = len(self.breach_frames)
        return (f"WARNING: the drone came within {self.lowest:.3f} m of the scene (frame {self.lowest_frame}), inside "
                f"its planner.safety_margin of {self.margin:g} m, in {n} frame(s): {list(self.breach_frames)}")


class FlightContact(FlightReconError):
    """The drone touched the scene in a flight that stops on contact; `event` is the contact."""

    def __init__(self, message: str, event: "ContactEvent") -> None:
        super().__init__(message)
        self.event = event


@dataclass(frozen=True)
class ContactEvent:
    time: float
    drone_geom: str
    other_geom: str
    position: tuple[float, float, float]
    penetration: float  # m, positive when the geoms overlap

    def describe(self) -> str:
        return (f"t={self.time:.3f}s contact {self.drone_geom} <-> {self.other_geom} at "
                f"({self.position[0]:.2f}, {self.position[1]:.2f}, {self.position[2]:.2f}), "
                f"penetration {1000 * self.penetration:.1f} mm")


class ContactMonitor:
    """Turns MuJoCo's contact list into start-of-contact events between the drone and the scene."""

    def __init__(self, model: mujoco.MjModel, drone_geom_ids: np.ndarray) -> None:
        self.model = model
        self.is_drone = np.zeros(model.ngeom, bool)
        self.is_drone[drone_geom_ids] = True
        self.active: set[tuple[int, int]] = set()

    def _name(self, gid: int) -> str:
        name = mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_GEOM, gid)
        if name:
            return name
        body = mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_BODY, self.model.geom_bodyid[gid])
        return f"geom {gid} of body {body or self.model.geom_bodyid[gid]}"

    def update(self, data: mujoco.MjData) -> list[ContactEvent]:
        """New contacts since the last call (pairs still touching are not reported again)."""
        n = data.ncon
        if n == 0:
            self.active.clear()
            return []
        con = data.contact
        g1, g2, dist = con.geom1[:n], con.geom2[:n], con.dist[:n]
        mine = (self.is_drone[g1] ^ self.is_drone[g2]) & (dist <= 0.0)
        current: set[tuple[int, int]] = set()
        events = []
        for k in np.flatnonzero(mine):
            a, b = (int(g1[k]), int(g2[k])) if self.is_drone[g1[k]] else (int(g2[k]), int(g1[k]))
            pair = (a, b)
            if pair in current:
                continue
            current.add(pair)
            if pair not in self.active:
                pos = con.pos[k]
                events.append(ContactEvent(float(data.time), self._name(a), self._name(b),
                                           (float(pos[0]), float(pos[1]), float(pos[2])), float(-dist[k])))
        self.active = current
        return events


def divergence_reason(values: list[float], cos_tilt: float, max_tilt_deg: float) -> str | None:
    """Why the state (its raw numbers, and the cosine of the body's tilt) is beyond recovery, or None."""
    if not math.isfinite(sum(values)):  # any NaN or inf makes the sum non-finite
        return "the simulated state holds NaN or inf"
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, cos_tilt))))
    if tilt > max_tilt_deg:
        return f"the drone tilted {tilt:.0f} deg, beyond the {max_tilt_deg:.0f} deg limit (sim.divergence_tilt_deg)"
    return None
