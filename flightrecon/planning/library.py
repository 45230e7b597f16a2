"""Viewpoint primitive library: the candidate views generated around the current viewpoint.

A candidate is an offset (forward, left, up, dyaw) applied GauSS-MI style: the heading turns first,
yaw' = yaw + dyaw, then the position moves by (forward, left) in the frame of the NEW heading and by
`up` vertically. The camera is fixed to the body, so a candidate has no pitch.

The default library is the paper's 198 candidates: 11 position offsets (stay; 0.3 and 0.6 m forward,
backward, left and right; 0.4 m up and down; GauSS-MI's step units) times 18 headings (every 20 deg
over the full turn). Because offsets are taken in the turned frame, the candidates spread over rings
of radius 0.3 m and 0.6 m around the drone at 36 bearings.

Built-in alternatives, for ablations: `no_stay` is the default without the current pose itself (197),
`moving` without any candidate at the current position (180: every view moves the drone; GauSS-MI's
library never offers the current position, at any heading), and `gaussmi` is GauSS-MI's own action library as its public
code builds it (active_manage.py `init_view_lib`: 94 sideways/vertical/turn actions in units of
0.3 m, 0.4 m and 40 deg, reaching 1.2 m sideways and 1.2 m vertically; no forward step, no stay and
no turn in place). A user library is a TOML file:

    [[candidate]]
    forward = 0.3   # m, all keys optional (default 0)
    left = 0.0
    up = 0.4
    yaw_deg = 40.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from flightrecon.config import read_toml
from flightrecon.errors import ConfigError

STEP_XY = 0.3  # m (GauSS-MI's lateral unit)
STEP_Z = 0.4  # m (GauSS-MI's vertical unit)
STEP_YAW_DEG = 40.0  # GauSS-MI's yaw unit
N_HEADINGS = 18
_KEYS = ("forward", "left", "up", "yaw_deg")


@dataclass(frozen=True)
class ViewpointLibrary:
    """Candidate offsets (M, 4): forward, left, up (m) and dyaw (rad)."""

    offsets: np.ndarray
    name: str = "default"

    def __len__(self) -> int:
        return len(self.offsets)

    def poses(self, position: np.ndarray, yaw: float) -> tuple[np.ndarray, np.ndarray]:
        """World positions (M, 3) and yaws (M,) of the candidates around a viewpoint.

        Yaws are wrapped to (-pi, pi]."""
        p = np.asarray(position, float).reshape(3)
        new_yaw = yaw + self.offsets[:, 3]
        c, s = np.cos(new_yaw), np.sin(new_yaw)
        fwd, left, up = self.offsets[:, 0], self.offsets[:, 1], self.offsets[:, 2]
        pos = p + np.stack([fwd * c - left * s, fwd * s + left * c, up], axis=1)
        return pos, wrap_angle(new_yaw)


def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    """Angle(s) wrapped to (-pi, pi]."""
    return -((-np.asarray(a, float) + math.pi) % (2 * math.pi) - math.pi)


def default_library() -> ViewpointLibrary:
    """The paper's 198 candidates (11 position offsets x 18 headings)."""
    moves = [(0.0, 0.0, 0.0)]
    for k in (1, 2):
        moves += [(k * STEP_XY, 0.0, 0.0), (-k * STEP_XY, 0.0, 0.0),
                  (0.0, k * STEP_XY, 0.0), (0.0, -k * STEP_XY, 0.0)]
    moves += [(0.0, 0.0, STEP_Z), (0.0, 0.0, -STEP_Z)]
    yaws = np.radians(np.arange(N_HEADINGS) * 360.0 / N_HEADINGS)
    yaws = wrap_angle(yaws)
    offsets = np.array([(f, l, u, y) for (f, l, u) in moves for y in yaws], float)
    return ViewpointLibrary(offsets, "default")


def no_stay_library() -> ViewpointLibrary:
    """The default library without the candidate that is the current pose (zero offset, zero turn)."""
    offsets = default_library().offsets
    return ViewpointLibrary(offsets[np.any(offsets != 0.0, axis=1)], "no_stay")


def moving_library() -> ViewpointLibrary:
    """The default library without the 18 headings at the current position."""
    offsets = default_library().offsets
    return ViewpointLibrary(offsets[np.any(offsets[:, :3] != 0.0, axis=1)], "moving")


def gaussmi_library() -> ViewpointLibrary:
    """GauSS-MI's 94 actions (sideways dy, vertical dz, turn dyaw) in its units, as (0, dy, dz, dyaw)."""
    actions = [(y, z, w) for y in (-2, -1, 0, 1, 2) for z in (-1, 0, 1) if (y, z) != (0, 0) for w in (-1, 0, 1)]
    actions += [(0, z, w) for z in (-3, -2, 2, 3) for w in (-1, 0, 1)]  # high
    actions += [(y, 0, w) for y in (-3, -2, -1, 1, 2, 3) for w in (-3, -2, 2, 3)]  # wide turns
    actions += [(y, z, w) for y in (-4, -3, 3, 4) for z in (-3, 3) for w in (-4, 4)]  # aggressive
    offsets = np.array([(0.0, y * STEP_XY, z * STEP_Z, math.radians(w * STEP_YAW_DEG)) for y, z, w in actions])
    return ViewpointLibrary(offsets, "gaussmi")


BUILT_IN = {"default": default_library, "no_stay": no_stay_library, "moving": moving_library,
            "gaussmi": gaussmi_library}


def load_library(spec: str) -> ViewpointLibrary:
    """A built-in library by name (default, no_stay, moving, gaussmi) or the path of a TOML file of
    [[candidate]] tables (see the module docstring)."""
    if spec in BUILT_IN:
        return BUILT_IN[spec]()
    path = Path(spec)
    data = read_toml(path, "planner.library: candidate file")
    extra = sorted(set(data) - {"candidate"})
    if extra:
        raise ConfigError(f"planner.library: {path}: unknown key '{extra[0]}' (expected [[candidate]] tables)")
    entries = data.get("candidate")
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"planner.library: {path} holds no [[candidate]] tables")
    rows = []
    for i, entry in enumerate(entries):
        if not isinstance(entry, dict):
            raise ConfigError(f"planner.library: {path}: candidate {i} is not a table")
        unknown = sorted(set(entry) - set(_KEYS))
        if unknown:
            raise ConfigError(f"planner.library: {path}: candidate {i}: unknown key '{unknown[0]}' "
                              f"(valid: {', '.join(_KEYS)})")
        row = []
        for key in _KEYS:
            v = entry.get(key, 0.0)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"planner.library: {path}: candidate {i}: '{key}' must be a finite number, got {v!r}")
            row.append(float(v))
        if abs(row[0]) > 20 or abs(row[1]) > 20 or abs(row[2]) > 20:
            raise ConfigError(f"planner.library: {path}: candidate {i}: offsets beyond 20 m are not local views")
        row[3] = math.radians(row[3])
        rows.append(row)
    return ViewpointLibrary(np.array(rows, float), path.stem)


def in_bounds(positions: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Mask of positions (N, 3) inside the workspace box `bounds` (2, 3)."""
    b = np.asarray(bounds, float)
    p = np.asarray(positions, float).reshape(-1, 3)
    return np.all((p >= b[0]) & (p <= b[1]), axis=1)
