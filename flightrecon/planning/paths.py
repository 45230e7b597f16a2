"""Geometric paths on a distance field: OMPL RRT-Connect with path simplification.

States and straight motions are valid when the distance field keeps the required clearance plus a
small Lipschitz margin at samples a quarter voxel apart, so the clearance also holds between them.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from flightrecon.planning.distance_field import DistanceField

_OMPL_READY = False


def _ompl():
    """Import OMPL once, quiet its Info logging and seed its global RNG for repeatable plans."""
    global _OMPL_READY
    from ompl import base as ob, geometric as og, util as ou

    if not _OMPL_READY:
        ou.setLogLevel(ou.LogLevel.LOG_ERROR)
        _OMPL_READY = True
    return ob, og, ou


def seed_ompl(seed: int) -> None:
    """Seed OMPL's global seed generator: the planners created afterwards sample repeatably.

    Re-seeding after planning has started works too (checked: same seed, same path); OMPL then
    logs an error that it may not, which is silenced here."""
    _, _, ou = _ompl()
    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    ou.RNG.setSeed(int(seed) % (2**31 - 1) + 1)  # OMPL rejects seed 0
    ou.setLogLevel(ou.LogLevel.LOG_ERROR)


def search_margin(field: DistanceField) -> float:
    """Clearance added to the requirement during the search, (3 + sqrt 3)/8 of a voxel.

    The trilinear field is sqrt(3)-Lipschitz at worst. Motions are validated at quarter-voxel steps,
    so anywhere on a validated segment the field is within sqrt(3)/8 voxel of the checked value; the
    trajectory check samples up to sqrt(3)/4 voxel apart and asks 3/8 voxel above the requirement.
    With this margin a path of straight legs timed rest to rest always passes that check."""
    return (3.0 + math.sqrt(3)) / 8 * field.voxel_size


def escape_point(field: DistanceField, start: np.ndarray, need: float, bounds: np.ndarray) -> np.ndarray | None:
    """Where a search may root for a start closer to obstacles than `need`: the start moved up the
    field's gradient in quarter-voxel steps until its clearance reaches `need` (a start in the band
    between the trajectory requirement and the search's margin could otherwise never get a detour,
    and turning in place never leaves that band). None when the clearance stops rising or the walk
    exceeds 2 `need` (a pocket: no escape along the gradient)."""
    step = field.voxel_size / 4
    b = np.asarray(bounds, float)
    p = np.asarray(start, float).copy()
    d = float(field.distance(p[None])[0])
    walked = 0.0
    while d < need:
        g = field.gradient(p[None])[0]
        norm = float(np.linalg.norm(g))
        if norm < 1e-6 or walked >= 2 * need:
            return None
        q = np.clip(p + step * g / norm, b[0], b[1])
        dq = float(field.distance(q[None])[0])
        if dq <= d:
            return None
        walked += float(np.linalg.norm(q - p))
        p, d = q, dq
    return p


def plan_path(field: DistanceField, start: np.ndarray, goal: np.ndarray, required: float,
              bounds: np.ndarray, time_limit: float, max_iterations: int = 300) -> np.ndarray | None:
    """Collision-free, simplified waypoints (W, 3) from start to goal, or None if none was found.

    Every state along the path (checked at a quarter voxel) keeps `required` clearance on `field`.
    The search stops after `max_iterations` planner iterations, so that with a seeded RNG the result
    does not depend on the machine's load; `time_limit` (s) is only a safety cap."""
    ob, og, _ = _ompl()
    b = np.asarray(bounds, float)
    step = field.voxel_size / 4
    need = required + search_margin(field)
    # All OMPL objects live in this frame only: nanobind then frees them before exit (no leak noise).
    space = ob.RealVectorStateSpace(3)
    rb = ob.RealVectorBounds(3)
    for k in range(3):
        rb.setLow(k, float(b[0, k]))
        rb.setHigh(k, float(b[1, k]))
    space.setBounds(rb)
    query = field.distance
    if np.any(query(np.stack([start, goal]).astype(float)) < need):
        return None  # no valid tree root: OMPL would only log an error
    ss = og.SimpleSetup(space)

    def valid(state) -> bool:
        return bool(query(np.array([[state[0], state[1], state[2]]]))[0] >= need)

    class SegmentValidator(ob.MotionValidator):
        """Checks a whole straight motion with one vectorized field query (a Python callback per
        interpolated state would dominate the planning time)."""

        def checkMotion(self, s1, s2, *_):
            a = np.array([s1[0], s1[1], s1[2]])
            c = np.array([s2[0], s2[1], s2[2]])
            n = max(int(math.ceil(np.linalg.norm(c - a) / step)), 1)
            pts = a + np.linspace(0.0, 1.0, n + 1)[:, None] * (c - a)
            return bool(np.all(query(pts) >= need))

    ss.setStateValidityChecker(valid)
    si = ss.getSpaceInformation()
    si.setMotionValidator(SegmentValidator(si))
    s, g = space.allocState(), space.allocState()
    for k in range(3):
        s[k] = float(start[k])
        g[k] = float(goal[k])
    ss.setStartAndGoalStates(s, g)
    ss.setPlanner(og.RRTConnect(si))
    iterations = [0]

    def exhausted() -> bool:
        iterations[0] += 1
        return iterations[0] > max_iterations

    ss.solve(ob.plannerOrTerminationCondition(ob.PlannerTerminationCondition(exhausted),
                                              ob.timedPlannerTerminationCondition(float(time_limit))))
    if not ss.haveExactSolutionPath():
        ss.clear()
        return None
    ss.simplifySolution()
    path = ss.getSolutionPath()
    out = np.array([[path.getState(i)[k] for k in range(3)] for i in range(path.getStateCount())])
    ss.clear()
    out[0], out[-1] = start, goal
    return out


class ReachableSpace:
    """Connected components of the grid centers whose clearance is at least `need`, built once and
    reused across one step's candidates to rule out hopeless searches without waiting out OMPL.

    Exact for states (not a heuristic): the trilinear field at a point is a convex combination of
    its cell's 8 corners, so along any continuous path with clearance >= need every cell crossed has
    such a corner on its entry and exit faces, and those corners are 26-neighbours. Hence if no
    corner of the start's cell shares a 26-connected component with a corner of the goal's cell,
    no valid path exists."""

    def __init__(self, field: DistanceField, need: float):
        self.field = field
        self.labels, _ = ndimage.label(field.values >= need, structure=np.ones((3, 3, 3), bool))

    def _corner_labels(self, point: np.ndarray) -> set[int]:
        f = self.field
        g = (np.asarray(point, float) - f.origin) / f.voxel_size - 0.5
        i0 = np.floor(g).astype(int)
        axes = [np.clip([i0[k], i0[k] + 1], 0, f.shape[k] - 1) for k in range(3)]
        block = self.labels[np.ix_(*axes)]
        return set(np.unique(block[block > 0]).tolist())

    def may_connect(self, a: np.ndarray, b: np.ndarray) -> bool:
        """False only when no path with the required clearance can join a and b."""
        return bool(self._corner_labels(a) & self._corner_labels(b))
