"""Procedural textures (albedo in [0, 1]) evaluated at points in a surface's own coordinates (metres).

Body parts are painted in their part frame, so the pattern moves with the part — what photometric
tracking needs; the mat, floor and the adult's leg in world coordinates. Patterns combine sharp
structure (stripes, checks, dots, tiles) with smooth value noise at several scales, so every patch of
surface is distinguishable from its neighbours at any image resolution.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np

#: Mat half-extent along x and y (metres): a 1.4 m × 1.0 m foam play mat centred at the origin.
MAT_HALF_SIZE = (0.7, 0.5)


_LATTICE = 1024  # lattice period in cells: patterns repeat only every 1024 cells


@functools.cache
def _lattice(salt: int) -> tuple[np.ndarray, np.ndarray]:
    """A permutation of the lattice and a random value per lattice index, fixed by ``salt``."""
    rng = np.random.default_rng(salt)
    return rng.permutation(_LATTICE), rng.random(_LATTICE)


def _hash01(cells: np.ndarray, salt: int) -> np.ndarray:
    """A deterministic pseudo-random value in [0, 1) per integer lattice cell [..., 3] (Perlin's hashing
    by chained permutation lookups: cheap gathers rather than arithmetic)."""
    perm, values = _lattice(salt)
    cells = cells.astype(np.int64)
    h = perm[cells[..., 0] & (_LATTICE - 1)]
    h = perm[(h + cells[..., 1]) & (_LATTICE - 1)]
    h = perm[(h + cells[..., 2]) & (_LATTICE - 1)]
    return values[h]


def value_noise(points: np.ndarray, cell: float, salt: int) -> np.ndarray:
    """Smooth noise in [0, 1] with feature size ``cell`` metres: lattice values blended trilinearly with
    smoothstep weights."""
    perm, values = _lattice(salt)
    mask = _LATTICE - 1
    p = points / cell
    base = np.floor(p)
    f = p - base
    f = f * f * (3 - 2 * f)
    (bx, by, bz), (fx, fy, fz) = base.astype(np.int64).T, f.T
    out = np.zeros(len(points))
    for i, wx in ((0, 1 - fx), (1, fx)):
        hx = perm[(bx + i) & mask]
        for j, wy in ((0, 1 - fy), (1, fy)):
            hxy = perm[(hx + by + j) & mask]
            wxy = wx * wy
            for k, wz in ((0, 1 - fz), (1, fz)):
                out += wxy * wz * values[perm[(hxy + bz + k) & mask]]
    return out


def fbm(points: np.ndarray, cell: float, salt: int, octaves: int = 3) -> np.ndarray:
    """Fractal noise in [0, 1]: ``octaves`` of value noise, each half the size and amplitude of the last."""
    total = np.zeros(len(points))
    for octave in range(octaves):
        total += 0.5**octave * value_noise(points, cell / 2**octave, salt + octave)
    return total / sum(0.5**octave for octave in range(octaves))


def _mix(a: np.ndarray, b: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Per-point blend of colours a and b ([3] or [N, 3]) by ``weight`` [N] in [0, 1]."""
    return a + (np.asarray(b) - a) * weight[:, None]


def _dots(points: np.ndarray, cell: float, radius: float, salt: int) -> np.ndarray:
    """[N] bool: inside one of the spheres jittered about a lattice of spacing ``cell`` (dots on a surface)."""
    base = np.floor(points / cell)
    centre = (base + 0.25 + 0.5 * np.stack([_hash01(base, salt + k) for k in range(3)], axis=-1)) * cell
    return np.linalg.norm(points - centre, axis=-1) < radius


def _shade_noise(colour: np.ndarray, points: np.ndarray, cell: float, salt: int, amount: float) -> np.ndarray:
    """Colour modulated in brightness by ±``amount`` of fractal noise."""
    return colour * (1 + amount * (2 * fbm(points, cell, salt) - 1))[:, None]


def skin(points: np.ndarray) -> np.ndarray:
    base = _mix(np.array([0.93, 0.74, 0.62]), np.array([0.88, 0.58, 0.52]), fbm(points, 0.03, 11))
    return _shade_noise(base, points, 0.012, 12, 0.08)


def head(points: np.ndarray) -> np.ndarray:
    """Skin with hair over the crown and back (the head frame's +x is the crown, +z the face) and a face."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    colour = skin(points)
    hair_line = 0.11 - 0.05 * np.clip(z / 0.06, -1, 1) + 0.012 * (fbm(points, 0.02, 13) - 0.5)
    hair = x > hair_line
    colour[hair] = _shade_noise(np.array([0.36, 0.25, 0.17]), points[hair], 0.006, 14, 0.25)
    face = z > 0.03
    for eye_y in (-0.024, 0.024):
        eye = face & (np.hypot(x - 0.088, y - eye_y) < 0.008)
        colour[eye] = [0.12, 0.09, 0.08]
    for cheek_y in (-0.036, 0.036):
        cheek = face & (np.hypot(x - 0.062, y - cheek_y) < 0.013)
        colour[cheek] = _mix(colour[cheek], [0.9, 0.5, 0.5], np.full(int(cheek.sum()), 0.5))
    mouth = face & (np.abs(y) < 0.011) & (np.abs(x - 0.045) < 0.0035)
    colour[mouth] = [0.72, 0.35, 0.38]
    return colour


def onesie(points: np.ndarray) -> np.ndarray:
    """Light blue and white bands 2 cm wide along the part (across the body and the sleeves), with yellow
    dots."""
    band = np.floor(points[:, 0] / 0.02) % 2
    colour = _mix(np.array([0.5, 0.7, 0.92]), np.array([0.96, 0.96, 0.94]), band)
    colour[_dots(points, 0.045, 0.011, 21)] = [0.97, 0.8, 0.25]
    return _shade_noise(colour, points, 0.025, 22, 0.1)


def diaper(points: np.ndarray) -> np.ndarray:
    colour = np.tile([0.95, 0.95, 0.92], (len(points), 1))
    colour[_dots(points, 0.035, 0.009, 31)] = [0.45, 0.78, 0.62]
    return _shade_noise(colour, points, 0.02, 32, 0.08)


def leggings(points: np.ndarray) -> np.ndarray:
    """Red and cream 2.5 cm checks."""
    checks = np.floor(points / 0.025).sum(axis=-1) % 2
    colour = _mix(np.array([0.82, 0.3, 0.32]), np.array([0.96, 0.86, 0.7]), checks)
    return _shade_noise(colour, points, 0.02, 41, 0.12)


def sock(points: np.ndarray) -> np.ndarray:
    """Yellow with a green cuff at the ankle (the foot frame's origin)."""
    colour = _mix(np.array([0.98, 0.88, 0.35]), np.array([0.3, 0.62, 0.4]), (points[:, 0] < 0.008).astype(float))
    return _shade_noise(colour, points, 0.015, 51, 0.12)


def mat_and_floor(points: np.ndarray) -> np.ndarray:
    """World xy: foam tiles 0.2 m wide in four pastel colours with dark seams on the mat; wooden planks
    along x around it."""
    on_mat = (np.abs(points[:, 0]) <= MAT_HALF_SIZE[0]) & (np.abs(points[:, 1]) <= MAT_HALF_SIZE[1])
    colour = np.empty((len(points), 3))
    colour[on_mat] = _mat(points[on_mat])
    colour[~on_mat] = _floor(points[~on_mat])
    return colour


def _mat(points: np.ndarray) -> np.ndarray:
    palette = np.array([[0.55, 0.76, 0.55], [0.93, 0.72, 0.45], [0.56, 0.66, 0.92], [0.92, 0.56, 0.6]])
    colour = palette[(_hash01(np.floor(points / 0.2), 61) * 4).astype(int)]
    distance = np.abs(points[:, :2] / 0.2 - np.round(points[:, :2] / 0.2)).min(axis=1) * 0.2
    colour[distance < 0.003] *= 0.55  # 6 mm seams between tiles
    return _shade_noise(colour, points, 0.05, 62, 0.12)


def _floor(points: np.ndarray) -> np.ndarray:
    """Planks 14 cm wide and 1.2 m long, staggered, each its own tone, with grain stretched along x."""
    x, y = points[:, 0], points[:, 1]
    row = np.floor(y / 0.14)
    plank = np.stack([np.floor(x / 1.2 + 0.37 * row), row, np.zeros_like(x)], axis=-1)
    tone = 0.75 + 0.25 * _hash01(plank, 63)
    grain = fbm(np.stack([x * 0.08, y, np.zeros_like(x)], axis=-1), 0.01, 64)
    return np.array([0.72, 0.55, 0.38]) * (tone * (0.85 + 0.3 * grain))[:, None]


def jeans(points: np.ndarray) -> np.ndarray:
    """The adult's leg (world coordinates): blue denim above a dark grey shoe."""
    colour = _shade_noise(np.array([0.22, 0.32, 0.52]), points, 0.04, 71, 0.2)
    colour[points[:, 2] < 0.1] = [0.25, 0.25, 0.27]
    return colour


#: Material name → albedo function of points [N, 3] → [N, 3].
MATERIALS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "skin": skin,
    "head": head,
    "onesie": onesie,
    "diaper": diaper,
    "leggings": leggings,
    "sock": sock,
    "mat": mat_and_floor,
    "jeans": jeans,
}


def albedo(material: str, points: np.ndarray) -> np.ndarray:
    """The colour [N, 3] in [0, 1] of ``material`` at ``points`` [N, 3]."""
    if len(points) == 0:
        return np.zeros((0, 3))
    return np.clip(MATERIALS[material](points), 0.0, 1.0)
