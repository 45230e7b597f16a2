"""The up direction of a scene mesh from its own geometry (`scene.up_axis = "auto"`).

Real scans are often stored in the coordinates of their first camera (BundleFusion, KinectFusion),
so their floor is perpendicular to no axis. Indoor scenes are dominated by a few planes: the floor,
the walls and (if scanned) the ceiling, plus furniture whose tops are level. So:

1. Dominant axes. A direction u explains the area of the faces whose normal is parallel to u
   (floor, ceiling, table tops: horizontal if u is up) plus those perpendicular to it (walls). The
   best of a few hundred candidate directions (area-weighted samples of the face normals) is one
   axis of the room's frame; the second is the best one perpendicular to it, the third completes it.
2. Which axis is up: three cues vote, and two must agree for the estimate to be confident.
   (a) Level area: the axis holding the most horizontal area (floor + ceiling + support surfaces,
   plus vertical faces at other headings than the walls). Alone it fails on open scans: without a
   ceiling, and with the floor half hidden by furniture, a pair of long walls holds more.
   (b) Support surfaces: furniture stands on the floor, so seats, beds and table tops face up
   SUPPORT_M (0.3-1.2 m) above the scan's bottom; along a wall axis, faces parallel to the wall at
   that distance face either way and are fewer. (c) Lowest extent: a room is lower than it is wide,
   so the axis along which the scan is shortest, when that is a room's height (ROOM_HEIGHT_M) and
   clearly shorter than the next (LOWEST_RATIO), is up; it abstains otherwise (a corridor, a tall
   hall). A tie goes to the level area.
3. Which way is up: the floor is the large horizontal layer at the BOTTOM of the scene, and the
   room's other horizontal surfaces (seats, tables, shelves, beds) stand on it, low in the room
   and facing up. The sign adds (a) the asymmetry of the horizontal area (faces within SIGN_DEG of
   level) in the lowest and highest tenth of the height (a scan without a ceiling has its floor
   alone at an end), (b) how low the horizontal area between the two ends lies, and (d) the
   support surfaces facing one way over the other (a fused scan's floor is often less complete than
   its ceiling, which (a) then reads the wrong way). The face winding ("normals pointing into the
   room") cannot tell a floor from a ceiling: swapping the sign swaps both the layers and which way
   counts as inward, so a floor facing up and a ceiling facing down score the same. Winding is used
   only where the mesh shows a consistent orientation at its ends (inward-facing scans): then level
   surfaces seen from above (table tops, whose undersides a scan rarely sees) point up (c). Closed
   synthetic meshes (every object a closed box, outer faces included) show none, and rely on the
   others. An upside-down mesh is detected this way.
4. Refinement: the up axis that maximizes the area-weighted sum of squared normal components of
   the horizontal faces minus those of the vertical faces (the top eigenvector of their signed
   normal scatter), which fits floor and walls together to far better than 0.5 deg.

Rotation (file -> world z-up, `world = rotation @ file`): the minimal rotation that maps the up
vector to +z, then a turn about world z by at most 45 deg that puts the dominant wall normal on
the world x or y axis, so the room's walls run along the axes of the axis-aligned workspace (a
first camera's heading is arbitrary anyway). When the estimate is confident and within SNAP_DEG of
a coordinate axis, that axis is used exactly with its exact 90/180-degree rotation and no turn, so
a file that already is z-up (or y-up) loads exactly as with `up_axis = "z"` (`"y"`).

Confidence: the floor's share of the surface area, the walls' (faces within 10 deg of vertical),
the floor normals' RMS spread about the axis, two cues agreeing on the axis, the sign margin, and a
room-sized extent
(at least MIN_HEIGHT_M tall with MIN_FLOOR_M2 of floor); a small object or a flat sheet is
"uncertain", and the loader then keeps the file's axes. Cost: a few vectorized passes over the faces.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

PAR_DEG = 10.0  # a face is parallel (perpendicular) to an axis within this angle
SIGN_DEG = 20.0  # level faces for the sign cues: wider, so noisy small floor faces still count
SAMPLES = 20000  # area-weighted normal samples scored against the candidates
CANDIDATES = 256  # candidate axes (the first samples)
LAYER = 0.1  # share of the height at each end that holds the floor (ceiling) layer
SNAP_DEG = 1.0  # a confident estimate this close to a coordinate axis is that axis exactly
ORIENTED = 0.5  # |orientation| of the end layers above which the face winding is trusted
MIN_HEIGHT_M = 1.0  # a room is at least this tall along the up axis
MIN_FLOOR_M2 = 1.0  # ... and has at least this much floor
MIN_FLOOR_COVER = 0.25  # the floor layer covers this share of the footprint at least
MIN_FLOOR_SHARE = 0.05  # share of the area in the floor layer
MIN_EXPLAINED = 0.35  # floor + walls share of the area (a furnished fused scan has half or less in them)
MAX_SPREAD_DEG = 6.0  # RMS angle of the floor normals about the axis
SUPPORT_M = (0.3, 1.2)  # m above the floor where seats, beds and tables hold level surfaces facing up
ROOM_HEIGHT_M = (1.2, 4.0)  # a room's height (or its walls' where the scan ends low)
LOWEST_RATIO = 0.85  # the up axis's extent is below this share of the next-lowest axis's
MIN_SIGN_MARGIN = 0.2  # |sign evidence|, which lies in [-3, 3]

_COS, _SIN = math.cos(math.radians(PAR_DEG)), math.sin(math.radians(PAR_DEG))

# exact minimal rotations taking a signed coordinate axis of the file to world +z
AXIS_ROTATIONS = {
    "z": np.eye(3),
    "-z": np.diag([1.0, -1.0, -1.0]),  # 180 deg about x
    "y": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),  # +90 deg about x
    "-y": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),  # -90 deg about x
    "x": np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]),  # -90 deg about y
    "-x": np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]),  # +90 deg about y
}
_AXES = {"x": (1.0, 0.0, 0.0), "-x": (-1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "-y": (0.0, -1.0, 0.0),
         "z": (0.0, 0.0, 1.0), "-z": (0.0, 0.0, -1.0)}


@dataclass(frozen=True)
class GravityEstimate:
    up: np.ndarray  # (3,) unit up vector in file coordinates
    rotation: np.ndarray  # (3, 3) world = rotation @ file; maps `up` to +z
    confident: bool
    floor_share: float  # share of the surface area in the floor layer
    wall_share: float  # share of the surface area within PAR_DEG of vertical
    floor_spread_deg: float  # area-weighted RMS angle of the floor normals about `up`
    axis_margin: float  # relative lead of the up axis's level area over the next candidate axis
    sign_margin: float  # |evidence| for the sign (0: a coin toss)
    cues: dict  # which axis each cue names (index into `axes` order: up first), and its figures
    snapped: str | None  # "z", "-y", ...: `up` is exactly that file axis
    reason: str  # why it is uncertain; "" when confident

    @property
    def label(self) -> str:
        return "confident" if self.confident else "uncertain"

    def to_dict(self) -> dict:
        return {"up": [round(float(x), 5) for x in self.up], "confidence": self.label,
                "floor_share": round(self.floor_share, 4), "wall_share": round(self.wall_share, 4),
                "floor_spread_deg": round(self.floor_spread_deg, 3), "axis_margin": round(self.axis_margin, 4),
                "sign_margin": round(self.sign_margin, 4), "cues": self.cues, "snapped": self.snapped,
                "reason": self.reason}


def rotation_to_z(up, wall: np.ndarray | None = None) -> np.ndarray:
    """The minimal rotation taking `up` to +z (exact for a coordinate axis); with `wall` (a
    direction perpendicular to `up`), then the turn about z of at most 45 deg that puts it on x or y."""
    u = np.asarray(up, np.float64)
    u = u / np.linalg.norm(u)
    for name, axis in _AXES.items():
        if np.array_equal(u, axis):
            R = AXIS_ROTATIONS[name].copy()
            break
    else:
        z = np.array([0.0, 0.0, 1.0])
        k = np.cross(u, z)
        s, c = float(np.linalg.norm(k)), float(u @ z)
        if s < 1e-12:  # u is +-z up to rounding
            R = np.eye(3) if c > 0 else AXIS_ROTATIONS["-z"].copy()
        else:
            K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
            R = np.eye(3) + K + K @ K * ((1.0 - c) / s ** 2)
    if wall is not None:
        w = R @ np.asarray(wall, np.float64)
        if math.hypot(w[0], w[1]) > 1e-9:
            phi = math.atan2(w[1], w[0])
            turn = -(phi - round(phi / (math.pi / 2)) * (math.pi / 2))
            if abs(turn) > 1e-12:
                ct, st = math.cos(turn), math.sin(turn)
                R = np.array([[ct, -st, 0.0], [st, ct, 0.0], [0.0, 0.0, 1.0]]) @ R
    return R


def estimate_up(vertices: np.ndarray, faces: np.ndarray, unit_scale: float = 1.0) -> GravityEstimate:
    """Estimate the up direction of an indoor scene mesh (file coordinates; `unit_scale` converts
    the file's units to meters for the room-size checks). See the module docstring."""
    v = np.asarray(vertices, np.float64)
    tri = v[np.asarray(faces)]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    dbl = np.linalg.norm(cross, axis=1)
    ok = dbl > 0
    if not ok.any():
        return _uncertain(np.array([0.0, 0.0, 1.0]), "the mesh has no face with an area")
    n = cross[ok] / dbl[ok, None]
    w = 0.5 * dbl[ok]
    w = w / w.sum()
    centers = tri[ok].sum(axis=1) / 3.0

    # 1. the room's frame: best candidate for parallel + perpendicular area, then the best one across it
    rng = np.random.default_rng(0)
    cdf = np.cumsum(w)
    idx = np.minimum(np.searchsorted(cdf, rng.random(SAMPLES) * cdf[-1]), len(w) - 1)
    ns = n[idx]
    cand = ns[:CANDIDATES]
    d = np.abs(ns @ cand.T)
    a1 = _refine(n, w, cand[int(np.argmax((d > _COS).sum(0) + (d < _SIN).sum(0)))])
    across = cand[np.abs(cand @ a1) < _SIN]
    across = across - np.outer(across @ a1, a1)
    if len(across):
        across /= np.linalg.norm(across, axis=1, keepdims=True)
        a2 = across[int(np.argmax((np.abs(ns @ across.T) > _COS).sum(0)))]
    else:
        a2 = np.cross(a1, np.eye(3)[int(np.argmin(np.abs(a1)))])
    a2 = _refine(n, w, a2, across=a1)
    axes = [a1, a2, np.cross(a1, a2)]

    # 2. the up axis: three cues vote (the module docstring); the level area breaks a tie
    dots = np.abs(n @ np.stack(axes, axis=1))  # (F, 3)
    par = dots > _COS
    off = [(dots[:, k] < _SIN) & ~par[:, [j for j in range(3) if j != k]].any(axis=1) for k in range(3)]
    score = np.array([w[par[:, k]].sum() + w[off[k]].sum() for k in range(3)])
    order = np.argsort(score)[::-1]
    axis_margin = float((score[order[0]] - score[order[1]]) / max(score[order[0]], 1e-12))
    support = np.array([[_support(n, w, v, centers, sgn * a, unit_scale) for sgn in (1.0, -1.0)] for a in axes])
    extent = np.array([float(np.ptp(v @ a)) * unit_scale for a in axes])
    low = np.argsort(extent)
    votes = {"level area": int(order[0]), "support surfaces": int(np.argmax(support.max(axis=1)))}
    if ROOM_HEIGHT_M[0] <= extent[low[0]] <= ROOM_HEIGHT_M[1] and extent[low[0]] < LOWEST_RATIO * extent[low[1]]:
        votes["lowest extent"] = int(low[0])
    count = np.bincount(list(votes.values()), minlength=3)
    k = int(order[0]) if count[order[0]] == count.max() else int(np.argmax(count))
    agree = sorted(name for name, j in votes.items() if j == k)
    up = _refine_up(n, w, axes[k])
    walls = [axes[j] for j in range(3) if j != k]
    wall = max(walls, key=lambda a: float(w[np.abs(n @ a) > _COS].sum()))

    # 3. the sign: the floor layer at the bottom, the room's level surfaces low above it and facing up
    s = n @ up
    h = centers @ up
    hv = v @ up
    lo, hi = float(hv.min()), float(hv.max())
    height = hi - lo
    flat = np.abs(s) > math.cos(math.radians(SIGN_DEG))
    t = (h - lo) / max(height, 1e-300)
    bot, top = flat & (t < LAYER), flat & (t > 1 - LAYER)
    mid = flat & ~bot & ~top
    wb, wt, wm = float(w[bot].sum()), float(w[top].sum()), float(w[mid].sum())
    ends = (wb - wt) / (wb + wt) if wb + wt > 0 else 0.0
    low_mid = 1.0 - 2.0 * float(np.average(t[mid], weights=w[mid])) if wm > 0 else 0.0
    orient = ((w[bot & (s > 0)].sum() + w[top & (s < 0)].sum() - w[bot & (s < 0)].sum() - w[top & (s > 0)].sum())
              / (wb + wt) if wb + wt > 0 else 0.0)
    seen_from_above = (w[mid & (s > 0)].sum() - w[mid & (s < 0)].sum()) / wm if wm > 0 else 0.0
    oriented = float(orient * seen_from_above) if abs(orient) > ORIENTED else 0.0
    up_side = _support(n, w, v, centers, up, unit_scale), _support(n, w, v, centers, -up, unit_scale)
    supported = (up_side[0] - up_side[1]) / sum(up_side) if sum(up_side) > 0 else 0.0
    evidence = ends + low_mid + oriented + supported
    if evidence < 0:
        up, s, t = -up, -s, 1.0 - t
    sign_margin = abs(evidence)
    disagree = ends * low_mid < 0 and min(abs(ends), abs(low_mid)) > 0.3 and abs(supported) < 0.5
    cues = {"axis": {name: ("up" if j == k else "other") for name, j in votes.items()},
            "support_share": round(float(support[k].max()), 4),
            "extent_m": [round(float(extent[k]), 3)] + [round(float(extent[j]), 3) for j in range(3) if j != k],
            "sign": {"ends": round(float(ends), 3), "low_level_area": round(float(low_mid), 3),
                     "winding": round(oriented, 3), "support": round(float(supported), 3)}}

    # confidence: how much floor + walls explain, how level the floor is, a room-sized extent
    bot = (np.abs(s) > _COS) & (t < LAYER)  # the floor layer
    floor_w = w[bot]
    floor_share = float(floor_w.sum())
    wall_share = float(w[np.abs(s) < _SIN].sum())
    ang = np.arccos(np.clip(np.abs(s[bot]), -1.0, 1.0))
    spread = math.degrees(math.sqrt(float(np.average(ang ** 2, weights=floor_w)))) if floor_share > 0 else 90.0
    total_area = 0.5 * float(dbl[ok].sum())
    h1 = v @ wall
    h2 = v @ np.cross(up, wall)
    footprint = float(np.ptp(h1) * np.ptp(h2))
    floor_area = floor_share * total_area
    checks = [
        (height * unit_scale >= MIN_HEIGHT_M, f"the scene is {height * unit_scale:.2f} m tall along the axis"),
        (floor_area * unit_scale ** 2 >= MIN_FLOOR_M2, f"the floor has {floor_area * unit_scale ** 2:.2f} m^2"),
        (floor_area >= MIN_FLOOR_COVER * footprint, "the floor layer covers little of the footprint"),
        (floor_share >= MIN_FLOOR_SHARE, f"the floor holds {floor_share:.0%} of the area"),
        (floor_share + wall_share >= MIN_EXPLAINED,
         f"floor and walls explain {floor_share + wall_share:.0%} of the area"),
        (spread <= MAX_SPREAD_DEG, f"the floor normals spread {spread:.1f} deg"),
        (len(agree) >= 2, "the cues name different up axes (" + ", ".join(
            f"{name}: {'this axis' if j == k else 'another'}" for name, j in votes.items()) + ")"),
        (sign_margin >= MIN_SIGN_MARGIN and not disagree,
         f"floor and ceiling are hard to tell apart (margin {sign_margin:.2f})"),
    ]
    failed = [why for passed, why in checks if not passed]
    confident = not failed
    snapped = None
    if confident:
        for name, axis in _AXES.items():
            if float(up @ np.asarray(axis)) > math.cos(math.radians(SNAP_DEG)):
                snapped, up = name, np.asarray(axis, np.float64)
                break
    R = AXIS_ROTATIONS[snapped].copy() if snapped else rotation_to_z(up, wall - (wall @ up) * up)
    return GravityEstimate(up=up, rotation=R, confident=confident, floor_share=floor_share,
                           wall_share=wall_share, floor_spread_deg=spread, axis_margin=axis_margin,
                           sign_margin=sign_margin, cues=cues, snapped=snapped, reason="; ".join(failed))


def _support(n: np.ndarray, w: np.ndarray, v: np.ndarray, centers: np.ndarray, up: np.ndarray,
             unit_scale: float) -> float:
    """Share of the area in level faces facing `up` at SUPPORT_M above the scan's bottom along it: the
    seats, beds and table tops furniture holds up, seen from above."""
    h = (centers @ up - float((v @ up).min())) * unit_scale
    facing = n @ up > math.cos(math.radians(SIGN_DEG))
    return float(w[facing & (h >= SUPPORT_M[0]) & (h <= SUPPORT_M[1])].sum())


def _refine(n: np.ndarray, w: np.ndarray, a: np.ndarray, across: np.ndarray | None = None) -> np.ndarray:
    """Area-weighted mean of the (sign-folded) normals parallel to `a`, shrinking the cone; `across`:
    keep the result perpendicular to that unit vector."""
    for deg in (PAR_DEG, 5.0, 3.0):
        s = n @ a
        near = np.abs(s) > math.cos(math.radians(deg))
        if not near.any():
            break
        m = (w[near] * np.sign(s[near])) @ n[near]
        if across is not None:
            m = m - (m @ across) * across
        norm = np.linalg.norm(m)
        if norm == 0:
            break
        a = m / norm
    return a


def _refine_up(n: np.ndarray, w: np.ndarray, a: np.ndarray) -> np.ndarray:
    """The axis maximizing sum(w (n.u)^2) over horizontal faces minus that over vertical ones."""
    for deg in (PAR_DEG, 3.0):
        c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
        d = np.abs(n @ a)
        sel = (d > c) | (d < s)
        sign = np.where(d[sel] > c, 1.0, -1.0) * w[sel]
        M = (n[sel] * sign[:, None]).T @ n[sel]
        vecs = np.linalg.eigh(M)[1]
        b = vecs[:, -1]
        a = b if b @ a >= 0 else -b
    return a / np.linalg.norm(a)


def _uncertain(up: np.ndarray, reason: str) -> GravityEstimate:
    return GravityEstimate(up=up, rotation=np.eye(3), confident=False, floor_share=0.0, wall_share=0.0,
                           floor_spread_deg=90.0, axis_margin=0.0, sign_margin=0.0, cues={}, snapped=None,
                           reason=reason)
