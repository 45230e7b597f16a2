"""Seeded procedural indoor scenes standing in for the paper's Replica scenes (office0-4, room0-2).

Each scene is a closed room (3-8 m across, 2.5-3 m high) built only from closed boxes and
cylinders, so depth never sees through to the outside; walls have door and window recesses, the
floor carries furniture of varied scale (thin chair legs and plant leaves down to tables, sofas,
shelves) and objects on surfaces, and every surface has a pattern baked into per-vertex colors.
A central column is kept free of furniture as the drone's take-off spot (meta 'spawn', 'free_box').
"""

from __future__ import annotations

import math
import zlib

import numpy as np

from flightrecon.errors import SceneError
from flightrecon.geometry import rot_x, rot_z
from flightrecon.scene import patterns as P
from flightrecon.scene.builder import Appearance, QuadMeshBuilder
from flightrecon.scene.replica_ply import quads_to_triangles
from flightrecon.scene.types import Scene

GENERATOR_VERSION = 1  # bump when the generator's output changes, so caches regenerate
SCENE_NAMES = ("office0", "office1", "office2", "office3", "office4", "room0", "room1", "room2")

WALL_T = 0.3  # wall thickness: door/window recesses are cut this deep at most
CELL_FLOOR, CELL_WALL, CELL_CEIL, CELL_FURN, CELL_FINE = 0.04, 0.05, 0.12, 0.03, 0.015
FREE_HALF = 0.7  # half side of the furniture-free column at the room center (m)

HIDE_OUTER = ("+y",)  # wall pieces: the face toward the outside


def make_scene(name: str, seed: int = 0) -> Scene:
    """Build the named procedural scene; the same (name, seed) always gives identical arrays."""
    if name not in SCENE_NAMES:
        raise SceneError(f"unknown procedural scene '{name}' (choose one of {', '.join(SCENE_NAMES)})")
    rng = np.random.default_rng([zlib.crc32(name.encode()), int(seed)])
    office = name.startswith("office")
    if office:
        L, W = rng.uniform(5.0, 8.0), rng.uniform(4.0, 6.5)
    else:
        L, W = rng.uniform(3.5, 6.0), rng.uniform(3.0, 5.0)
    H = rng.uniform(2.5, 3.0)
    b = QuadMeshBuilder()
    openings = _shell(b, rng, L, W, H)
    placer = _Placer(L, W, rng)
    if office:
        _furnish_office(b, rng, placer, L, W)
    else:
        _furnish_room(b, rng, placer, L, W)
    _wall_art(b, rng, L, W, H, openings, count=int(rng.integers(2, 5)))
    verts, colors, normals, quads = b.build()
    meta = {
        "generator": "flightrecon.procedural", "kind": "office" if office else "room", "seed": int(seed),
        "quad_faces": True, "floor_z": 0.0, "ceiling_z": float(H),
        "room_box": [[-L / 2, -W / 2, 0.0], [L / 2, W / 2, float(H)]],
        "free_box": [[-FREE_HALF, -FREE_HALF, 0.3], [FREE_HALF, FREE_HALF, float(H) - 0.3]],
        "spawn": [0.0, 0.0, 0.0], "openings": openings,
    }
    return Scene(name=name, vertices=verts.astype(np.float64), faces=quads_to_triangles(quads),
                 vertex_colors=colors, vertex_normals=normals.astype(np.float64), meta=meta)


def _shift(app: Appearance, ds: float, dt: float) -> Appearance:
    """The same pattern seen from a face whose (s, t) origin is offset, so walls stay continuous."""
    return lambda s, t: app(s + ds, t + dt)


def _walls(L: float, W: float) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(inner-plane start point, outward normal, length) of the four walls; x-walls cover corners."""
    return [
        (np.array([L / 2, W / 2, 0.0]), np.array([1.0, 0.0, 0.0]), W),
        (np.array([-L / 2, -W / 2, 0.0]), np.array([-1.0, 0.0, 0.0]), W),
        (np.array([-L / 2 - WALL_T, W / 2, 0.0]), np.array([0.0, 1.0, 0.0]), L + 2 * WALL_T),
        (np.array([L / 2 + WALL_T, -W / 2, 0.0]), np.array([0.0, -1.0, 0.0]), L + 2 * WALL_T),
    ]


def _wall_frame(o: np.ndarray) -> np.ndarray:
    """Rotation whose x runs along the wall (o x z), y points outward, z up."""
    z = np.array([0.0, 0.0, 1.0])
    return np.stack([np.cross(o, z), o, z], axis=1)


def _shell(b: QuadMeshBuilder, rng, L: float, W: float, H: float) -> list[dict]:
    """Floor, ceiling and four thick walls with door and window recesses; returns the openings."""
    floor_app = [P.wood(rng), P.tiles(rng), P.carpet(rng)][int(rng.integers(0, 3))]
    b.box([0, 0, -0.05], [L + 2 * WALL_T, W + 2 * WALL_T, 0.1],
          {"+z": _shift(floor_app, L / 2 + WALL_T, W / 2 + WALL_T)}
          | {k: P.solid([0.5] * 3, rng) for k in ("-z", "+x", "-x", "+y", "-y")},
          CELL_FLOOR, hidden=("-z", "+x", "-x", "+y", "-y"))
    ceil = P.solid(rng.uniform(0.85, 0.97, 3), rng, variation=0.03)
    b.box([0, 0, H + 0.05], [L + 2 * WALL_T, W + 2 * WALL_T, 0.1], ceil, CELL_CEIL,
          hidden=("+z", "+x", "-x", "+y", "-y"))
    wall_app = P.plaster(rng)
    openings = []
    kinds = ["door"] + ["window"] * int(rng.integers(1, 3))
    wall_ids = rng.permutation(4)
    for w, (start, o, length) in enumerate(_walls(L, W)):
        R = _wall_frame(o)
        ops = []
        for k, wid in enumerate(wall_ids):
            if wid == w and k < len(kinds):
                ops.append(kinds[k])
        pieces = [(0.0, length, 0.0, H)]
        if ops:
            kind = ops[0]
            width = rng.uniform(0.8, 1.0) if kind == "door" else rng.uniform(0.9, min(1.8, length - 1.2))
            a0 = rng.uniform(0.6 + (WALL_T if length > min(L, W) + 0.1 else 0), length - 0.6 - width)
            z0, z1 = (0.0, rng.uniform(2.0, min(2.2, H - 0.2))) if kind == "door" else \
                (rng.uniform(0.8, 1.0), rng.uniform(min(2.0, H - 0.35), H - 0.3))
            a1 = a0 + width
            pieces = [(0.0, a0, 0.0, H), (a1, length, 0.0, H), (a0, a1, z1, H)]
            if z0 > 0:
                pieces.append((a0, a1, 0.0, z0))
            depth = rng.uniform(0.15, WALL_T - 0.08)
            back = P.wood(rng, along_s=False) if kind == "door" else _window_view(rng)
            c = start + R[:, 0] * (a0 + a1) / 2 + o * (depth + 0.05) + np.array([0, 0, (z0 + z1) / 2])
            b.box(c, [width + 0.02, 0.1, z1 - z0 + 0.02], {"-y": back} | {k: wall_app for k in
                  ("+x", "-x", "+y", "+z", "-z")}, CELL_FURN, R=R, hidden=("+x", "-x", "+y", "+z", "-z"))
            p0 = start + R[:, 0] * a0
            openings.append({"kind": kind, "start": p0.tolist(), "end": (p0 + R[:, 0] * width).tolist(),
                             "z": [float(z0), float(z1)], "depth": float(depth)})
        for a0, a1, z0, z1 in pieces:
            c = start + R[:, 0] * (a0 + a1) / 2 + o * WALL_T / 2 + np.array([0, 0, (z0 + z1) / 2])
            app = {"-y": _shift(wall_app, a0, z0), "+x": wall_app, "-x": wall_app, "+z": wall_app,
                   "-z": wall_app, "+y": wall_app}
            b.box(c, [a1 - a0, WALL_T, z1 - z0], app, CELL_WALL, R=R, hidden=HIDE_OUTER)
    return openings


def _window_view(rng) -> Appearance:
    """A window pane: sky gradient, a skyline silhouette and mullions."""
    sky = rng.uniform(0.5, 0.9, 3) * np.array([0.7, 0.85, 1.0])
    salt = int(rng.integers(0, 1 << 20))

    def f(s, t):
        col = sky[None] * (0.75 + 0.25 * t / max(t.max(initial=1.0), 1e-6))[:, None]
        skyline = 0.3 + 0.4 * P._hash2(np.floor(s / 0.12), np.floor(s / 0.12) * 0, salt)
        col[t < skyline] = [0.3, 0.32, 0.35]
        mull = (np.abs(s % 0.45) < 0.025) | (np.abs(t % 0.5) < 0.025)
        col[mull] = [0.92, 0.92, 0.9]
        return col
    return f


class _Placer:
    """Non-overlapping axis-aligned footprints on the floor; the center column stays free."""

    def __init__(self, L: float, W: float, rng) -> None:
        self.L, self.W, self.rng = L, W, rng
        self.rects = [(-FREE_HALF, -FREE_HALF, FREE_HALF, FREE_HALF)]

    def _free(self, r, margin: float = 0.12) -> bool:
        x0, y0, x1, y1 = r
        if x0 < -self.L / 2 or x1 > self.L / 2 or y0 < -self.W / 2 or y1 > self.W / 2:
            return False
        return not any(x0 < b[2] + margin and b[0] - margin < x1 and y0 < b[3] + margin and b[1] - margin < y1
                       for b in self.rects)

    def against_wall(self, w: float, d: float, tries: int = 60):
        """Footprint w x d with its back to a random wall: (center xy, yaw facing the room) or None."""
        for _ in range(tries):
            side = int(self.rng.integers(0, 4))
            if side < 2:  # walls at x = -L/2 (side 0) or +L/2 (side 1), item width along y
                half = self.W / 2 - w / 2
                if half <= 0:
                    continue
                y = self.rng.uniform(-half, half)
                x = -self.L / 2 + d / 2 + 0.01 if side == 0 else self.L / 2 - d / 2 - 0.01
                rect = (x - d / 2, y - w / 2, x + d / 2, y + w / 2)
                yaw = 0.0 if side == 0 else math.pi
            else:
                half = self.L / 2 - w / 2
                if half <= 0:
                    continue
                x = self.rng.uniform(-half, half)
                y = -self.W / 2 + d / 2 + 0.01 if side == 2 else self.W / 2 - d / 2 - 0.01
                rect = (x - w / 2, y - d / 2, x + w / 2, y + d / 2)
                yaw = math.pi / 2 if side == 2 else -math.pi / 2
            if self._free(rect):
                self.rects.append(rect)
                return np.array([x, y]), yaw
        return None

    def anywhere(self, w: float, d: float, tries: int = 60):
        """Footprint w x d (rotated by a multiple of 90 deg) anywhere free: (center, yaw) or None."""
        for _ in range(tries):
            yaw = float(self.rng.integers(0, 4)) * math.pi / 2
            ww, dd = (w, d) if int(round(yaw / (math.pi / 2))) % 2 == 0 else (d, w)
            x = self.rng.uniform(-self.L / 2 + dd / 2, self.L / 2 - dd / 2)
            y = self.rng.uniform(-self.W / 2 + ww / 2, self.W / 2 - ww / 2)
            rect = (x - dd / 2, y - ww / 2, x + dd / 2, y + ww / 2)
            if self._free(rect):
                self.rects.append(rect)
                return np.array([x, y]), yaw
        return None


def _local(center_xy, yaw: float):
    """Map local furniture coordinates (x forward into the room, y left, z up) to the world."""
    R = rot_z(yaw)
    c = np.array([center_xy[0], center_xy[1], 0.0])
    return lambda p: c + R @ np.asarray(p, float), R


# ---------------------------------------------------------------------------------------- furniture

def _table(b, rng, at, yaw, w, d, h, top_app, leg_app, objects: bool = True) -> None:
    to, R = _local(at, yaw)
    t = 0.03
    b.box(to([0, 0, h - t / 2]), [d, w, t], top_app, CELL_FURN, R=R)
    leg = rng.uniform(0.025, 0.05)
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.box(to([sx * (d / 2 - leg), sy * (w / 2 - leg), (h - t) / 2]), [leg, leg, h - t], leg_app,
                  CELL_FURN, R=R, hidden=("-z",))
    if objects:
        _tabletop_objects(b, rng, to, R, w, d, h)


def _tabletop_objects(b, rng, to, R, w, d, h) -> None:
    """A monitor or laptop, a book stack and a mug: small objects on the surface."""
    if rng.uniform() < 0.6:
        sw, sh = rng.uniform(0.45, 0.65), rng.uniform(0.28, 0.38)
        sw = min(sw, w)  # a screen on a narrow cabinet; other scenes are unchanged
        y = rng.uniform(-w / 2 + sw / 2, w / 2 - sw / 2)
        b.box(to([-d / 4, y, h + 0.005]), [0.18, 0.22, 0.01], P.metal([0.2] * 3, rng), CELL_FURN, R=R)
        b.box(to([-d / 4, y, h + 0.12]), [0.03, 0.05, 0.22], P.metal([0.2] * 3, rng), CELL_FURN, R=R)
        screen = P.text_poster(rng, sw, sh)
        b.box(to([-d / 4 + 0.03, y, h + 0.1 + sh / 2]), [0.02, sw, sh],
              {"+x": lambda s, t: screen(sw - s, t), "-x": P.solid([0.1] * 3, rng),
               "+y": P.solid([0.1] * 3, rng), "-y": P.solid([0.1] * 3, rng), "+z": P.solid([0.1] * 3, rng),
               "-z": P.solid([0.1] * 3, rng)}, CELL_FINE, R=R)
    for _ in range(int(rng.integers(1, 4))):
        x, y = rng.uniform(-d / 2 + 0.12, d / 2 - 0.12), rng.uniform(-w / 2 + 0.12, w / 2 - 0.12)
        z = h
        for _ in range(int(rng.integers(1, 4))):
            bh = rng.uniform(0.02, 0.05)
            bw, bd = rng.uniform(0.15, 0.25), rng.uniform(0.1, 0.18)
            b.box(to([x, y, z + bh / 2]), [bd, bw, bh], P.solid(rng.uniform(0.1, 0.9, 3), rng, 0.1),
                  CELL_FURN, R=R @ rot_z(rng.uniform(-0.4, 0.4)), hidden=("-z",))
            z += bh
    x, y = rng.uniform(-d / 2 + 0.08, d / 2 - 0.08), rng.uniform(-w / 2 + 0.08, w / 2 - 0.08)
    b.cylinder(to([x, y, h]), 0.04, 0.045, 0.1, P.solid(rng.uniform(0.2, 1.0, 3), rng), 12, CELL_FURN)


def _chair(b, rng, at, yaw, fabric_app, leg_app) -> None:
    """Chair with thin legs (2-2.5 cm) and a backrest: thin structures for the mapper."""
    to, R = _local(at, yaw)
    s, h = rng.uniform(0.42, 0.5), rng.uniform(0.43, 0.48)
    leg = rng.uniform(0.02, 0.025)
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.box(to([sx * (s / 2 - leg), sy * (s / 2 - leg), h / 2]), [leg, leg, h], leg_app, CELL_FURN,
                  R=R, hidden=("-z",))
    b.box(to([0, 0, h + 0.03]), [s, s, 0.06], fabric_app, CELL_FURN, R=R)
    bh = rng.uniform(0.35, 0.5)
    for sy in (-1, 1):
        b.box(to([-s / 2 + leg, sy * (s / 2 - leg), h + 0.06 + bh / 2]), [leg, leg, bh], leg_app, CELL_FURN, R=R)
    b.box(to([-s / 2 + 0.02, 0, h + 0.06 + bh * 0.7]), [0.03, s, bh * 0.5], fabric_app, CELL_FURN, R=R)


def _shelf(b, rng, at, yaw, w, d, h) -> None:
    """Open bookcase: side panels, back, shelves with rows of books."""
    to, R = _local(at, yaw)
    wood = P.wood(rng)
    t = 0.02
    for sy in (-1, 1):
        b.box(to([0, sy * (w / 2 - t / 2), h / 2]), [d, t, h], wood, CELL_FURN, R=R, hidden=("-z",))
    b.box(to([-d / 2 + t / 2, 0, h / 2]), [t, w - 2 * t, h], wood, CELL_FURN, R=R, hidden=("-x", "-z"))
    n = int(rng.integers(3, 6))
    levels = np.linspace(0.05, h - t / 2, n + 1)
    for z in levels:
        b.box(to([t / 2, 0, z]), [d - t, w - 2 * t, t], wood, CELL_FURN, R=R)
    for z0, z1 in zip(levels[:-1], levels[1:]):
        if rng.uniform() < 0.8:
            bw = rng.uniform(0.4, 1.0) * (w - 2 * t - 0.02)
            bh = min(z1 - z0 - t - 0.03, rng.uniform(0.18, 0.3))
            if bh < 0.08:
                continue
            y = rng.uniform(-(w - 2 * t - bw) / 2, (w - 2 * t - bw) / 2)
            spines = P.book_spines(rng)
            bd = d - t - 0.05
            b.box(to([t / 2 + 0.02, y, z0 + t / 2 + bh / 2]), [bd, bw, bh],
                  {"+x": _shift(spines, 0, 0)} | {k: P.solid([0.9, 0.88, 0.8], rng) for k in
                                                 ("-x", "+y", "-y", "+z", "-z")}, CELL_FURN, R=R,
                  hidden=("-x", "-z"))
        else:  # a vase
            b.cylinder(to([0.0, rng.uniform(-w / 4, w / 4), z0 + t / 2]), 0.05, 0.035,
                       min(0.2, z1 - z0 - 0.05), P.solid(rng.uniform(0.2, 0.9, 3), rng), 14, CELL_FURN)


def _cabinet(b, rng, at, yaw, w, d, h) -> None:
    """Closed cabinet with drawer seams and small handles."""
    to, R = _local(at, yaw)
    body = P.wood(rng) if rng.uniform() < 0.5 else P.solid(rng.uniform(0.3, 0.95, 3), rng)
    drawers = int(rng.integers(2, 5))

    def front(s, t):
        c = body(s, t)
        seam = (np.abs((t / h * drawers) - np.round(t / h * drawers)) * h / drawers < 0.006)
        c[seam] *= 0.4
        return c
    b.box(to([0, 0, h / 2]), [d, w, h], {"+x": front} | {k: body for k in ("-x", "+y", "-y", "+z", "-z")},
          CELL_FURN, R=R, hidden=("-x", "-z"))
    for k in range(drawers):
        zc = (k + 0.5) * h / drawers
        b.box(to([d / 2 + 0.015, 0, zc]), [0.03, 0.12, 0.02], P.metal([0.75] * 3, rng), CELL_FURN, R=R)
    if rng.uniform() < 0.6:
        _tabletop_objects(b, rng, to, R, w, d, h)


def _sofa(b, rng, at, yaw, w) -> None:
    to, R = _local(at, yaw)
    fab = P.fabric(rng)
    d, seat = 0.85, 0.42
    b.box(to([0, 0, 0.12]), [d, w, 0.2], fab, CELL_FURN, R=R, hidden=("-z",))
    for sy in (-1, 1):
        b.box(to([0, sy * (w / 2 - 0.1), 0.35]), [d, 0.2, 0.46], fab, CELL_FURN, R=R)
    b.box(to([-d / 2 + 0.1, 0, 0.55]), [0.2, w - 0.4, 0.65], fab, CELL_FURN, R=R)
    n = max(2, int(round((w - 0.4) / 0.7)))
    cw = (w - 0.4) / n
    for k in range(n):
        y = -w / 2 + 0.2 + cw * (k + 0.5)
        b.box(to([0.1, y, seat - 0.05]), [d - 0.2, cw - 0.02, 0.14], fab, CELL_FURN, R=R)
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.cylinder(to([sx * (d / 2 - 0.06), sy * (w / 2 - 0.06), 0.0]), 0.02, 0.015, 0.02,
                       P.solid([0.15] * 3, rng), 8, CELL_FURN)


def _lamp(b, rng, at) -> None:
    """Floor lamp: a heavy base, a 1.2 cm pole and a conical shade."""
    to, R = _local(at, 0.0)
    h = rng.uniform(1.4, 1.75)
    met = P.metal(rng.uniform(0.2, 0.8, 3), rng)
    b.cylinder(to([0, 0, 0]), 0.15, 0.13, 0.03, met, 20, CELL_FURN)
    b.cylinder(to([0, 0, 0.03]), 0.012, 0.012, h - 0.03, met, 8, 0.05)
    shade = P.fabric(rng)
    b.cylinder(to([0, 0, h - 0.1]), 0.22, 0.14, 0.28, shade, 24, CELL_FURN)


def _plant(b, rng, at) -> None:
    """Potted plant: a pot, thin stems and leaves as 4 mm plates at many angles."""
    to, R = _local(at, 0.0)
    pot_h = rng.uniform(0.25, 0.4)
    b.cylinder(to([0, 0, 0]), 0.13, 0.17, pot_h, P.solid(rng.uniform(0.3, 0.9, 3), rng), 20, CELL_FURN)
    b.cylinder(to([0, 0, pot_h]), 0.16, 0.16, 0.005, P.solid([0.25, 0.18, 0.1], rng), 20, CELL_FURN)
    leaf = P.foliage(rng)
    stem_app = P.solid([0.3, 0.4, 0.15], rng)
    for _ in range(int(rng.integers(4, 8))):
        sh = rng.uniform(0.3, 0.8)
        sx, sy = rng.uniform(-0.06, 0.06, 2)
        b.cylinder(to([sx, sy, pot_h]), 0.006, 0.005, sh, stem_app, 6, 0.05)
        for _ in range(int(rng.integers(2, 4))):
            z = pot_h + rng.uniform(0.4, 1.0) * sh
            lw, ll = rng.uniform(0.05, 0.1), rng.uniform(0.15, 0.3)
            ang = rng.uniform(0, 2 * math.pi)
            Rl = rot_z(ang) @ rot_x(0.0)
            tilt = rng.uniform(-0.6, 0.3)
            Rl = Rl @ np.array([[math.cos(tilt), 0, math.sin(tilt)], [0, 1, 0], [-math.sin(tilt), 0, math.cos(tilt)]])
            c = to([sx, sy, z]) + Rl @ np.array([ll / 2, 0, 0])
            b.box(c, [ll, lw, 0.004], leaf, 0.025, R=Rl)


def _rug(b, rng, at, yaw, w, d) -> None:
    to, R = _local(at, yaw)
    b.box(to([0, 0, 0.006]), [d, w, 0.012], P.carpet(rng), CELL_FLOOR, R=R, hidden=("-z",))


def _bed(b, rng, at, yaw, w, d) -> None:
    to, R = _local(at, yaw)
    b.box(to([0, 0, 0.2]), [d, w, 0.4], P.wood(rng), CELL_FURN, R=R, hidden=("-z",))
    b.box(to([0.02, 0, 0.5]), [d - 0.04, w - 0.04, 0.2], P.fabric(rng), CELL_FURN, R=R)
    b.box(to([-d / 2 + 0.04, 0, 0.75]), [0.08, w, 0.7], P.wood(rng), CELL_FURN, R=R)
    for sy in (-1, 1):
        b.box(to([-d / 2 + 0.3, sy * w / 4, 0.66]), [0.3, w / 2 - 0.1, 0.12], P.fabric(rng), CELL_FURN, R=R)


def _tv(b, rng, at, yaw, w) -> None:
    """Low TV stand with a screen showing a picture."""
    to, R = _local(at, yaw)
    _cabinet_like = P.wood(rng)
    b.box(to([0, 0, 0.25]), [0.4, w, 0.5], _cabinet_like, CELL_FURN, R=R, hidden=("-x", "-z"))
    sw, sh = min(w - 0.1, rng.uniform(0.9, 1.3)), 0.6
    pic = P.text_poster(rng, sw, sh)
    b.box(to([-0.08, 0, 0.5 + 0.05 + sh / 2]), [0.04, sw, sh],
          {"+x": lambda s, t: pic(sw - s, t)} | {k: P.solid([0.08] * 3, rng) for k in ("-x", "+y", "-y", "+z", "-z")},
          CELL_FINE, R=R)


def _wall_art(b, rng, L, W, H, openings, count: int) -> None:
    """Posters and whiteboards with text-like patterns flat on wall segments clear of openings."""
    walls = _walls(L, W)
    for _ in range(count * 4):
        if count == 0:
            break
        w_id = int(rng.integers(0, 4))
        start, o, length = walls[w_id]
        R = _wall_frame(o)
        pw, ph = rng.uniform(0.4, 1.2), rng.uniform(0.5, 0.9)
        lo = WALL_T if length > min(L, W) + 0.1 else 0.0
        if length - 2 * lo - pw < 0.4:
            continue
        a = rng.uniform(lo + 0.2, length - lo - 0.2 - pw)
        z = rng.uniform(1.2, H - 0.25 - ph)
        p0 = start + R[:, 0] * a
        p1 = p0 + R[:, 0] * pw
        clash = any(np.linalg.norm(np.array(op["start"]) + np.array(op["end"]) - p0 - p1) / 2
                    < (pw + np.linalg.norm(np.array(op["end"]) - np.array(op["start"]))) / 2 + 0.1
                    for op in openings)
        if clash:
            continue
        poster = P.text_poster(rng, pw, ph)
        c = (p0 + p1) / 2 - o * 0.0075 + np.array([0, 0, z + ph / 2])
        frame = P.solid(rng.uniform(0.05, 0.9, 3), rng)
        b.box(c, [pw, 0.015, ph], {"-y": poster} | {k: frame for k in ("+x", "-x", "+y", "+z", "-z")},
              CELL_FINE, R=R, hidden=("+y",))
        openings.append({"kind": "poster", "start": p0.tolist(), "end": p1.tolist(), "z": [z, z + ph],
                         "depth": -0.015})
        count -= 1


def _furnish_office(b, rng, pl: _Placer, L, W) -> None:
    top = P.wood(rng)
    legs = P.metal(rng.uniform(0.15, 0.8, 3), rng)
    chair_fab = P.fabric(rng)
    for _ in range(int(rng.integers(2, 4))):
        w, d = rng.uniform(1.2, 1.6), rng.uniform(0.65, 0.8)
        spot = pl.against_wall(w, d + 0.65)  # desk plus room for its chair
        if spot is None:
            continue
        xy, yaw = spot
        fwd = rot_z(yaw)[:2, 0]
        _table(b, rng, xy - fwd * 0.325, yaw, w, d, rng.uniform(0.72, 0.76), top, legs)
        _chair(b, rng, xy + fwd * (d / 2 + 0.05), yaw + math.pi + rng.uniform(-0.4, 0.4), chair_fab, legs)
    spot = pl.anywhere(rng.uniform(1.6, 2.4), rng.uniform(0.9, 1.1))
    if spot is not None:  # meeting table with chairs around it
        xy, yaw = spot
        _table(b, rng, xy, yaw, rng.uniform(1.4, 1.8), rng.uniform(0.8, 0.9), 0.74, top, legs)
    for _ in range(int(rng.integers(1, 3))):
        w, h = rng.uniform(0.8, 1.2), rng.uniform(1.6, 2.1)
        spot = pl.against_wall(w, 0.32)
        if spot is not None:
            _shelf(b, rng, *spot, w, 0.32, h)
    for _ in range(int(rng.integers(1, 3))):
        w, h = rng.uniform(0.5, 1.0), rng.uniform(0.7, 1.2)
        spot = pl.against_wall(w, 0.45)
        if spot is not None:
            _cabinet(b, rng, *spot, w, 0.45, h)
    _decor(b, rng, pl)


def _furnish_room(b, rng, pl: _Placer, L, W) -> None:
    spot = pl.against_wall(rng.uniform(1.6, 2.2), 0.85)
    if spot is not None:
        xy, yaw = spot
        _sofa(b, rng, xy, yaw, min(2.2, rng.uniform(1.6, 2.2)))
    spot = pl.anywhere(rng.uniform(0.9, 1.2), rng.uniform(0.5, 0.7))
    if spot is not None:
        _table(b, rng, *spot, 1.0, 0.6, 0.42, P.wood(rng), P.wood(rng))
    if rng.uniform() < 0.5:
        spot = pl.against_wall(1.5, 2.0)
        if spot is not None:
            _bed(b, rng, *spot, 1.4, 2.0)
    spot = pl.against_wall(rng.uniform(1.0, 1.5), 0.4)
    if spot is not None:
        xy, yaw = spot
        _tv(b, rng, xy, yaw, 1.4)
    spot = pl.against_wall(rng.uniform(0.8, 1.1), 0.32)
    if spot is not None:
        _shelf(b, rng, *spot, 0.9, 0.32, rng.uniform(1.2, 1.9))
    spot = pl.against_wall(0.6, 0.45)
    if spot is not None:
        _cabinet(b, rng, *spot, 0.6, 0.45, rng.uniform(0.5, 0.8))
    for _ in range(int(rng.integers(1, 3))):
        spot = pl.anywhere(0.45, 0.45)
        if spot is not None:
            _chair(b, rng, spot[0], spot[1] + rng.uniform(-0.5, 0.5), P.fabric(rng), P.wood(rng))
    _decor(b, rng, pl)
    _rug(b, rng, [0.0, 0.0], 0.0, min(2.0, W - 0.8), min(2.6, L - 0.8))


def _decor(b, rng, pl: _Placer) -> None:
    for _ in range(int(rng.integers(1, 3))):
        spot = pl.against_wall(0.45, 0.45)
        if spot is not None:
            _lamp(b, rng, spot[0])
    for _ in range(int(rng.integers(1, 4))):
        spot = pl.anywhere(0.4, 0.4)
        if spot is not None:
            _plant(b, rng, spot[0])
