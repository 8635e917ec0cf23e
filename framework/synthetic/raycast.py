"""Analytic ray intersections, vectorised over rays: an ellipsoid, a capsule, a sphere and the ground
plane. Rays start at one ``origin`` [3] and run along ``directions`` [N, 3] (not necessarily unit
length); a hit is reported as the ray parameter s > 0 of the nearest intersection (``inf`` for a miss)."""

from __future__ import annotations

import numpy as np

#: Hits nearer than this ray parameter are ignored (the camera is never inside a surface).
NEAR = 1e-6


def _nearest_root(half_b: np.ndarray, a: np.ndarray, c: np.ndarray) -> np.ndarray:
    """The smaller root of a·s² + 2·half_b·s + c = 0 when it exceeds :data:`NEAR`, else ``inf``."""
    disc = half_b * half_b - a * c
    with np.errstate(divide="ignore", invalid="ignore"):  # a = 0: a ray parallel to a capsule's axis
        root = (-half_b - np.sqrt(np.maximum(disc, 0.0))) / a
    return np.where((disc >= 0) & (root > NEAR), root, np.inf)


def intersect_ellipsoid(
    origin: np.ndarray, directions: np.ndarray, rotation: np.ndarray, centre: np.ndarray, radii: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """s [N] to an ellipsoid (axes the columns of ``rotation``, world ``centre``, semi-axes ``radii``), and
    unit [N, 3]: the hit in the ellipsoid's frame scaled to the unit sphere (the hit in the ellipsoid's
    frame is ``unit * radii``; meaningless for a miss)."""
    scaled = rotation / radii  # maps world offsets to the frame in which the ellipsoid is the unit sphere
    o = (origin - centre) @ scaled
    d = directions @ scaled
    s = _nearest_root(d @ o, np.einsum("ni,ni->n", d, d), np.full(len(d), o @ o - 1))
    return s, o + np.where(np.isfinite(s), s, 0.0)[:, None] * d


def intersect_capsule(origin: np.ndarray, directions: np.ndarray, a: np.ndarray, b: np.ndarray, radius: float) -> np.ndarray:
    """s [N] to a capsule: the points within ``radius`` of the segment from ``a`` to ``b``."""
    axis = b - a
    length2 = axis @ axis
    oa = origin - a
    d_axis, oa_axis = directions @ axis, oa @ axis
    # The side: the infinite cylinder, kept where the hit projects inside the segment.
    side = _nearest_root(
        length2 * (directions @ oa) - oa_axis * d_axis,
        length2 * np.einsum("ni,ni->n", directions, directions) - d_axis**2,
        np.full(len(directions), length2 * (oa @ oa) - oa_axis**2 - radius**2 * length2),
    )
    along = oa_axis + side * d_axis
    side = np.where((along >= 0) & (along <= length2), side, np.inf)
    caps = [intersect_sphere(origin, directions, end, radius) for end in (a, b)]
    return np.minimum(side, np.minimum(*caps))


def intersect_sphere(origin: np.ndarray, directions: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """s [N] to a sphere."""
    oc = origin - centre
    return _nearest_root(directions @ oc, np.einsum("ni,ni->n", directions, directions), np.full(len(directions), oc @ oc - radius**2))


def intersect_ground(origin: np.ndarray, directions: np.ndarray, half_size: float) -> np.ndarray:
    """s [N] to the plane z = 0 within the square |x|, |y| ≤ ``half_size``, seen from above."""
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -origin[2] / directions[:, 2]
    point = origin[:2] + s[:, None] * directions[:, :2]
    inside = (s > NEAR) & np.all(np.abs(point) <= half_size, axis=1)
    return np.where(inside, s, np.inf)
