"""Surface appearance for procedural scenes: deterministic value noise and material patterns.

Each factory takes a numpy Generator (so one seed drives every choice) and returns an
`Appearance`: a function of metric surface coordinates (s, t) giving RGB in [0, 1].
"""

from __future__ import annotations

import numpy as np

from flightrecon.scene.builder import Appearance


def _hash2(ix: np.ndarray, iy: np.ndarray, salt: int) -> np.ndarray:
    """Deterministic hash of integer lattice points to [0, 1) (no global RNG state)."""
    h = (ix.astype(np.int64) * 374761393 + iy.astype(np.int64) * 668265263 + salt * 2246822519) & 0xFFFFFFFF
    h = ((h ^ (h >> 13)) * 1274126177) & 0xFFFFFFFF
    h = h ^ (h >> 16)
    return (h & 0xFFFFFF).astype(np.float64) / float(1 << 24)


def value_noise(s: np.ndarray, t: np.ndarray, scale: float, salt: int, octaves: int = 3) -> np.ndarray:
    """Smooth fractal noise in [0, 1] with features of size `scale` (m) and finer octaves."""
    total = np.zeros_like(s, dtype=np.float64)
    amp, norm = 1.0, 0.0
    for o in range(octaves):
        x, y = s / scale * (2 ** o), t / scale * (2 ** o)
        ix, iy = np.floor(x), np.floor(y)
        fx, fy = x - ix, y - iy
        fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
        v00 = _hash2(ix, iy, salt + o)
        v10 = _hash2(ix + 1, iy, salt + o)
        v01 = _hash2(ix, iy + 1, salt + o)
        v11 = _hash2(ix + 1, iy + 1, salt + o)
        total += amp * ((v00 * (1 - fx) + v10 * fx) * (1 - fy) + (v01 * (1 - fx) + v11 * fx) * fy)
        norm += amp
        amp *= 0.5
    return total / norm


def _mix(c0, c1, w: np.ndarray) -> np.ndarray:
    c0, c1 = np.asarray(c0, float), np.asarray(c1, float)
    return c0 + (c1 - c0) * w[:, None]


def _salt(rng: np.random.Generator) -> int:
    return int(rng.integers(0, 1 << 20))


def solid(color, rng: np.random.Generator, variation: float = 0.04) -> Appearance:
    """Painted or plastic surface: a color with faint large-scale mottling."""
    salt = _salt(rng)
    c = np.asarray(color, float)

    def f(s, t):
        n = value_noise(s, t, 0.4, salt, octaves=2) - 0.5
        return c[None] * (1.0 + 2 * variation * n[:, None])
    return f


def wood(rng: np.random.Generator, along_s: bool = True) -> Appearance:
    """Wood grain: stretched noise rings along the board direction, with plank seams."""
    salt = _salt(rng)
    base = np.array([0.55, 0.36, 0.2]) * rng.uniform(0.7, 1.25)
    dark = base * 0.55
    plank = rng.uniform(0.12, 0.25)
    freq = rng.uniform(25.0, 45.0)

    def f(s, t):
        a, b = (s, t) if along_s else (t, s)
        warp = value_noise(a * 0.15, b, 0.08, salt, octaves=2)
        rings = 0.5 + 0.5 * np.sin((b + 0.06 * warp) * freq + 6.0 * value_noise(a, b, 0.5, salt + 7, 2))
        board = np.floor(b / plank)
        shade = 0.85 + 0.3 * _hash2(board, board * 0, salt)
        seam = (np.abs(b / plank - np.round(b / plank)) * plank < 0.004).astype(float)
        col = _mix(base, dark, 0.6 * rings ** 3) * shade[:, None]
        return col * (1 - 0.5 * seam[:, None])
    return f


def tiles(rng: np.random.Generator) -> Appearance:
    """Square tiles with per-tile tone jitter and dark grout lines."""
    salt = _salt(rng)
    size = rng.uniform(0.25, 0.6)
    c0 = rng.uniform(0.55, 0.95, 3)
    c1 = c0 * rng.uniform(0.6, 0.9)
    grout = np.array([0.25, 0.25, 0.27])

    def f(s, t):
        ix, iy = np.floor(s / size), np.floor(t / size)
        checker = ((ix + iy) % 2).astype(float) * 0.5 + 0.5 * _hash2(ix, iy, salt)
        col = _mix(c0, c1, checker) * (0.95 + 0.1 * value_noise(s, t, 0.05, salt + 1, 2))[:, None]
        gx = np.abs(s / size - np.round(s / size)) * size
        gy = np.abs(t / size - np.round(t / size)) * size
        g = ((gx < 0.008) | (gy < 0.008)).astype(float)
        return col * (1 - g[:, None]) + grout * g[:, None]
    return f


def carpet(rng: np.random.Generator) -> Appearance:
    """Carpet: a dyed base with fine fibrous noise and a faint large pattern."""
    salt = _salt(rng)
    base = rng.uniform(0.15, 0.7, 3)
    alt = np.clip(base * rng.uniform(0.5, 1.5, 3), 0, 1)

    def f(s, t):
        fine = value_noise(s, t, 0.03, salt, octaves=2)
        blotch = value_noise(s, t, 0.6, salt + 3, octaves=2)
        stripes = (np.sin((s + t) * 9.0) > 0.6).astype(float) * 0.5
        return _mix(base, alt, 0.6 * blotch + 0.4 * stripes) * (0.8 + 0.4 * fine)[:, None]
    return f


def plaster(rng: np.random.Generator) -> Appearance:
    """Painted wall with a darker wainscot band near the floor and subtle mottling."""
    salt = _salt(rng)
    base = rng.uniform(0.65, 0.95, 3)
    band = base * rng.uniform(0.45, 0.75, 3)
    band_h = rng.uniform(0.6, 1.0)

    def f(s, t):
        n = value_noise(s, t, 0.3, salt, octaves=3)
        col = _mix(base, band, (t < band_h).astype(float))
        line = (np.abs(t - band_h) < 0.015).astype(float)
        return col * (0.92 + 0.16 * n)[:, None] * (1 - 0.4 * line[:, None])
    return f


def fabric(rng: np.random.Generator) -> Appearance:
    """Upholstery: a weave of two crossing thread directions over a dyed base."""
    salt = _salt(rng)
    base = rng.uniform(0.15, 0.8, 3)

    def f(s, t):
        weave = 0.5 + 0.25 * (np.sin(s * 180.0) + np.sin(t * 180.0))
        n = value_noise(s, t, 0.15, salt, octaves=2)
        return base[None] * (0.75 + 0.25 * weave + 0.2 * (n - 0.5))[:, None]
    return f


def foliage(rng: np.random.Generator) -> Appearance:
    """Leaves: green shades with veins."""
    salt = _salt(rng)
    base = np.array([0.15, 0.45, 0.12]) * rng.uniform(0.7, 1.3)

    def f(s, t):
        vein = (np.abs(np.sin(s * 60.0 + t * 30.0)) > 0.95).astype(float)
        n = value_noise(s, t, 0.05, salt, octaves=2)
        return base[None] * (0.7 + 0.6 * n)[:, None] + 0.25 * vein[:, None]
    return f


def text_poster(rng: np.random.Generator, width: float, height: float) -> Appearance:
    """Poster: a colored title block, an image-like gradient panel and lines of text-like words."""
    salt = _salt(rng)
    paper = rng.uniform(0.85, 1.0, 3)
    accent = rng.uniform(0.05, 0.9, 3)
    ink = rng.uniform(0.0, 0.25, 3)
    line_h = rng.uniform(0.025, 0.04)
    margin = 0.06 * min(width, height)
    title_h = 0.22 * height
    panel = (margin, 0.25 * height, width - margin, 0.45 * height)

    def f(s, t):
        u = height - t  # read top to bottom
        col = np.broadcast_to(paper, (len(s), 3)).copy()
        title = (u < title_h) & (u > margin)
        col[title] = accent
        in_panel = (s > panel[0]) & (s < panel[2]) & (t > panel[1]) & (t < panel[3])
        g = value_noise(s, t, 0.12, salt + 1, octaves=3)
        col[in_panel] = _mix(accent[::-1], accent * 0.4, g[in_panel])
        body = (u > title_h + margin) & (t > panel[3] + margin) | (t < panel[1] - margin) & (t > margin)
        row = np.floor(u / line_h)
        in_row = (u / line_h - row) < 0.55
        word = np.floor(s / 0.05 + 3 * _hash2(row, row * 0, salt))
        gap = _hash2(word, row, salt + 2) < 0.22
        line_len = width * (0.5 + 0.45 * _hash2(row, row * 0 + 1, salt + 3))
        ink_mask = body & in_row & ~gap & (s > margin) & (s < line_len)
        col[ink_mask] = ink
        return col
    return f


def book_spines(rng: np.random.Generator) -> Appearance:
    """A row of book spines: random widths and colors with a title band."""
    salt = _salt(rng)

    def f(s, t):
        book = np.floor(s / 0.035 + 0.5 * value_noise(s, s * 0, 0.2, salt, 1))
        c = np.stack([_hash2(book, book * 0 + k, salt) for k in range(3)], axis=1) * 0.8 + 0.1
        band = (np.abs(t - 0.7 * t.max(initial=0.0)) < 0.02).astype(float)
        return c * (1 - 0.6 * band[:, None]) + 0.6 * band[:, None]
    return f


def metal(color, rng: np.random.Generator) -> Appearance:
    """Brushed metal: streaks along s."""
    salt = _salt(rng)
    c = np.asarray(color, float)

    def f(s, t):
        streak = value_noise(s * 0.05, t, 0.004, salt, octaves=1)
        return c[None] * (0.85 + 0.3 * streak)[:, None]
    return f
