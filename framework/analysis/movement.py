"""Measures of movement from landmark trajectories, as a clinician or movement scientist reads them: how
fast, how far and over what range each body part moved, how alike the left and right sides moved, and
at which rhythms — the time and frequency description of infant movement that the Computer-based Infant
Movement Assessment uses.

Trajectories are ``times`` [T] seconds and ``positions`` [T, L, 3] metres, NaN where a landmark is unknown.
Every function skips unknown frames rather than inventing them; a landmark without enough known frames
gets ``None`` for what cannot be measured.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

#: One plain sentence per measure of :func:`movement_summary`, for the report.
MEASURE_DESCRIPTIONS = {
    "mean_speed_m_s": "average speed over the recording",
    "peak_speed_m_s": "the speed reached in the fastest 5 % of moments (the 95th percentile)",
    "path_length_m": "the total distance travelled along the path",
    "range_of_motion_m": "how far apart the extreme positions are: the largest, over the three axes, of the spread between the 5th and 95th percentile positions",
    "dominant_frequency_hz": "the rhythm with the most power in the speed, in cycles per second: a limb swinging back and forth f times a second speeds up twice per swing, so its speed peaks at 2f; coarse for short recordings",
    "spectral_centroid_hz": "the power-weighted mean frequency of the speed: higher for quicker, more fidgety movement",
}
MIN_FRAMES = 4  # known frames below which a speed-based measure is not given
LOW_FREQUENCY_HZ = 0.1  # the spectrum's lower edge: slower "rhythms" are drift, not movement


def speed(times: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """[T, L] speed (m/s) at every frame: central differences inside, one-sided at the ends; NaN where a
    neighbouring frame is unknown."""
    times = np.asarray(times, dtype=np.float64)
    positions = np.asarray(positions, dtype=np.float64)
    if len(times) < 2:
        return np.full(positions.shape[:2], np.nan)
    velocity = np.gradient(positions, times, axis=0)
    return np.linalg.norm(velocity, axis=-1)


def path_length(positions: np.ndarray) -> np.ndarray:
    """[L] metres travelled: the sum of the steps between consecutive frames where both are known."""
    steps = np.linalg.norm(np.diff(np.asarray(positions, dtype=np.float64), axis=0), axis=-1)
    return np.nansum(steps, axis=0)


def range_of_motion(positions: np.ndarray) -> np.ndarray:
    """[L] metres: per axis the spread between the 5th and 95th percentile positions (one stray frame does
    not set it), the largest of the three."""
    positions = np.asarray(positions, dtype=np.float64)
    result = np.full(positions.shape[1], np.nan)
    for j in range(positions.shape[1]):
        known = positions[np.all(np.isfinite(positions[:, j]), axis=1), j]
        if len(known):
            result[j] = float(np.max(np.percentile(known, 95, axis=0) - np.percentile(known, 5, axis=0)))
    return result


def speed_spectrum(times: np.ndarray, track: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(frequencies Hz, power) of one landmark's speed (``track`` [T, 3]) by Welch's method, its mean
    removed, from 0.1 Hz to the Nyquist frequency; empty arrays when fewer than 8 frames are known. Unknown
    frames are filled by linear interpolation before the transform."""
    from scipy.signal import welch

    series = speed(times, np.asarray(track, dtype=np.float64)[:, None])[:, 0]
    known = np.isfinite(series)
    if known.sum() < 8:
        return np.zeros(0), np.zeros(0)
    index = np.arange(len(series))
    series = np.interp(index, index[known], series[known])
    rate = 1.0 / float(np.median(np.diff(times)))
    frequencies, power = welch(series - series.mean(), fs=rate, nperseg=min(len(series), 64), detrend=False)
    band = frequencies >= LOW_FREQUENCY_HZ
    return frequencies[band], power[band]


def _side(name: str) -> tuple[str, str] | None:
    """(side "left"/"right", the rest of the name) of ``LWrist``, ``left_wrist``, ``wrist left``, …; None
    for a name without a side."""
    lowered = name.lower()
    for side in ("left", "right"):
        for pattern in (rf"^{side}[\s_\-]*(.+)$", rf"^(.+?)[\s_\-]*{side}$"):
            match = re.match(pattern, lowered)
            if match:
                return side, match.group(1).strip(" _-")
    match = re.match(r"^([LR])([A-Z].*)$", name)  # Pose2Sim / OpenPose: LWrist, RBigToe
    if match:
        return ("left" if match.group(1) == "L" else "right"), match.group(2).lower()
    return None


def limb_pairs(names: tuple[str, ...] | list[str]) -> list[tuple[str, str]]:
    """(left name, right name) of every landmark that has a counterpart on the other side, in name order."""
    sides: dict[tuple[str, str], str] = {}
    for name in names:
        found = _side(name)
        if found:
            sides[found] = name
    return [(sides[("left", part)], sides[("right", part)]) for side, part in sides if side == "left" and ("right", part) in sides]


def limb_landmarks(names: tuple[str, ...] | list[str]) -> dict[str, str]:
    """The landmark standing for each of "left hand", "right hand", "left foot", "right foot": the wrist
    for a hand; the ankle for a foot, else the heel, else the big toe. Limbs without one are left out."""
    chosen: dict[str, tuple[int, str]] = {}
    for name in names:
        found = _side(name)
        if not found:
            continue
        side, part = found[0], re.sub(r"[\s_\-]", "", found[1])
        for limb, preferences in (("hand", ("wrist",)), ("foot", ("ankle", "heel", "bigtoe"))):
            if part in preferences:
                key, rank = f"{side} {limb}", preferences.index(part)
                if key not in chosen or rank < chosen[key][0]:
                    chosen[key] = (rank, name)
    order = ("left hand", "right hand", "left foot", "right foot")
    return {key: chosen[key][1] for key in order if key in chosen}


def _number(value: float) -> float | None:
    return round(float(value), 6) if np.isfinite(value) else None


def _correlation(a: np.ndarray, b: np.ndarray) -> float | None:
    both = np.isfinite(a) & np.isfinite(b)
    if both.sum() < MIN_FRAMES or np.std(a[both]) == 0 or np.std(b[both]) == 0:
        return None
    return _number(np.corrcoef(a[both], b[both])[0, 1])


def movement_summary(names: tuple[str, ...] | list[str], times: np.ndarray, positions: np.ndarray) -> dict[str, Any]:
    """JSON-ready measures: ``landmarks`` {name: {measure: value}} with the keys of
    :data:`MEASURE_DESCRIPTIONS`, ``pairs`` [{left, right, speed_correlation, path_length_ratio}],
    ``duration_s`` and ``frame_rate_hz``."""
    times = np.asarray(times, dtype=np.float64)
    positions = np.asarray(positions, dtype=np.float64)
    speeds = speed(times, positions)
    lengths = path_length(positions)
    ranges = range_of_motion(positions)
    landmarks: dict[str, dict[str, float | None]] = {}
    for j, name in enumerate(names):
        known = np.isfinite(speeds[:, j])
        if known.sum() < MIN_FRAMES:
            landmarks[name] = dict.fromkeys(MEASURE_DESCRIPTIONS)
            continue
        frequencies, power = speed_spectrum(times, positions[:, j])
        has_spectrum = len(frequencies) and power.sum() > 0
        landmarks[name] = {
            "mean_speed_m_s": _number(np.nanmean(speeds[:, j])),
            "peak_speed_m_s": _number(np.nanpercentile(speeds[:, j], 95)),
            "path_length_m": _number(lengths[j]),
            "range_of_motion_m": _number(ranges[j]),
            "dominant_frequency_hz": _number(frequencies[np.argmax(power)]) if has_spectrum else None,
            "spectral_centroid_hz": _number((frequencies * power).sum() / power.sum()) if has_spectrum else None,
        }
    index = {name: j for j, name in enumerate(names)}
    pairs = []
    for left, right in limb_pairs(names):
        a, b = lengths[index[left]], lengths[index[right]]
        pairs.append({"left": left, "right": right, "speed_correlation": _correlation(speeds[:, index[left]], speeds[:, index[right]]),
                      "path_length_ratio": _number(a / b) if b > 0 else None})
    return {"landmarks": landmarks, "pairs": pairs, "duration_s": _number(times[-1] - times[0]) if len(times) else None,
            "frame_rate_hz": _number(1.0 / np.median(np.diff(times))) if len(times) > 1 else None}
