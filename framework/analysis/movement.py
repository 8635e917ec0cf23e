"""Measures of movement from landmark trajectories, as a clinician or movement scientist reads them: how
fast, how far and over what range each body part moved, how alike the left and right sides moved, and
at which rhythms — the time and frequency description of spontaneous movement that, for infants, the
Computer-based Infant Movement Assessment builds on.

Each measure is one entry of a table — :data:`LANDMARK_MEASURES` (per landmark), :data:`PAIR_MEASURES`
(per left/right pair), :data:`JOINT_ANGLES` (per side, per frame) — naming its function, its unit and one
sentence the report prints; :func:`movement_summary` computes every entry, so a new measure is one function
plus its entry (docs/landmarks.md, "Adding a measure").

Trajectories are ``times`` [T] seconds (uniform or nearly), ``positions`` [T, L, 3] metres, NaN where a
landmark is unknown at a frame, and ``names`` [L]. Every function skips unknown frames rather than
inventing them; a landmark without enough known frames gets ``None`` for what cannot be measured.
Everything here is a pure function of its arguments (numpy and scipy only).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from typing import Any

import attrs
import numpy as np

MIN_FRAMES = 5  # known frames (or frames known on both sides) below which a speed-based measure or a correlation is not given
MIN_SPECTRUM_FRAMES = 8  # known frames below which no spectrum is given
LOW_FREQUENCY_HZ = 0.1  # the spectrum's lower edge: slower "rhythms" are drift over the recording, not movement
MAX_SEGMENT = 256  # Welch's segment length at most (frames): 8.5 s at 30 fps, a 0.12 Hz resolution
PERCENTILES = (5.0, 95.0)  # the range of motion's spread
PEAK_PERCENTILE = 95.0  # the peak speed


# --------------------------------------------------------------------------------------------------
# Per landmark


def _known(positions: np.ndarray) -> np.ndarray:
    """[T, L] True where all three coordinates are known."""
    return np.all(np.isfinite(positions), axis=-1)


def smooth_positions(positions: np.ndarray, window: int = 0, order: int = 2) -> np.ndarray:
    """The trajectories smoothed in time by a Savitzky–Golay filter (a moving least-squares polynomial of
    ``order`` over ``window`` frames), applied to each run of consecutive known frames on its own so that no
    unknown frame is filled in; runs shorter than the window are left as they are.

    Why smooth: a landmark jittering by a millimetre or two between frames adds tens of mm/s of speed and
    inflates the path length, though the limb did not move. Savitzky–Golay removes that jitter while keeping
    the peaks of real movement better than a moving average. ``window`` 0 (the default) or below ``order`` + 2
    returns the positions unchanged; 5 to 9 frames at 30 fps is a light smoothing, which leaves slow limb
    movements (a few Hz) almost untouched but flattens the first and last frames' speeds of each run a little
    less faithfully than its middle (the fitted polynomial is extrapolated there)."""
    positions = np.array(positions, dtype=np.float64)
    if window <= order + 1 or positions.shape[0] < window:
        return positions
    from scipy.signal import savgol_filter

    window = window if window % 2 else window + 1
    known = _known(positions)
    for j in range(positions.shape[1]):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], known[:, j].astype(np.int8), [0]])))
        for start, stop in zip(edges[::2], edges[1::2], strict=True):
            if stop - start >= window:
                positions[start:stop, j] = savgol_filter(positions[start:stop, j], window, order, axis=0)
    return positions


def speed(times: np.ndarray, positions: np.ndarray, smoothing_window: int = 0) -> np.ndarray:
    """[T, L] speed (m/s) of every landmark at every frame: the distance between the previous and the next
    frame's positions over the time between them (a central difference); where only one neighbour is known,
    the step to that neighbour (at the ends, and beside gaps). NaN where the landmark is unknown at the frame
    or at both its neighbours.

    ``smoothing_window`` > 0 first smooths the positions (:func:`smooth_positions`); the default, 0, measures
    the positions as they are, so that the speed is not changed by a choice of filter."""
    times = np.asarray(times, dtype=np.float64)
    positions = smooth_positions(positions, smoothing_window)
    result = np.full(positions.shape[:2], np.nan)
    if len(times) < 2:
        return result
    step = np.diff(positions, axis=0) / np.diff(times)[:, None, None]  # [T-1, L, 3]: velocity between frames t and t+1
    forward = np.full(positions.shape, np.nan)
    backward = np.full(positions.shape, np.nan)
    forward[:-1], backward[1:] = step, step
    central = np.full(positions.shape, np.nan)
    if len(times) > 2:
        central[1:-1] = (positions[2:] - positions[:-2]) / (times[2:] - times[:-2])[:, None, None]
    velocity = central
    for fallback in (backward, forward):
        missing = ~np.all(np.isfinite(velocity), axis=-1)
        velocity = np.where(missing[..., None], fallback, velocity)
    result = np.linalg.norm(velocity, axis=-1)
    result[~_known(positions)] = np.nan
    return result


def mean_speed(speeds: np.ndarray) -> np.ndarray:
    """[L] the average speed (m/s) of each landmark over the frames where it is known (``speeds`` [T, L]
    from :func:`speed`); NaN for a landmark with fewer than ``MIN_FRAMES`` known."""
    speeds = np.asarray(speeds, dtype=np.float64)
    enough = np.isfinite(speeds).sum(axis=0) >= MIN_FRAMES
    return np.array([np.nanmean(speeds[:, j]) if enough[j] else np.nan for j in range(speeds.shape[1])])


def peak_speed(speeds: np.ndarray, percentile: float = PEAK_PERCENTILE) -> np.ndarray:
    """[L] the peak speed (m/s) of each landmark: the 95th percentile of its known speeds rather than the
    maximum, so that one glitching frame does not set it. NaN with fewer than ``MIN_FRAMES`` known."""
    speeds = np.asarray(speeds, dtype=np.float64)
    enough = np.isfinite(speeds).sum(axis=0) >= MIN_FRAMES
    return np.array([np.nanpercentile(speeds[:, j], percentile) if enough[j] else np.nan for j in range(speeds.shape[1])])


def path_length(positions: np.ndarray) -> np.ndarray:
    """[L] metres each landmark travelled: the sum of the straight steps between consecutive frames where
    it is known at both; a step into or out of a gap is left out (the path through the gap is unknown), so
    a landmark with gaps gets a lower bound. NaN for a landmark with no such step."""
    positions = np.asarray(positions, dtype=np.float64)
    if positions.shape[0] < 2:
        return np.full(positions.shape[1], np.nan)
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=-1)  # NaN where either end is unknown
    valid = np.isfinite(steps)
    return np.where(valid.any(axis=0), np.where(valid, steps, 0.0).sum(axis=0), np.nan)


def range_of_motion_axes(positions: np.ndarray, percentiles: tuple[float, float] = PERCENTILES) -> np.ndarray:
    """[L, 3] metres: for each landmark and each axis of the calibration (x, y, z), the spread between the
    5th and 95th percentile of its known positions — the extent it covered, leaving out the most extreme
    10 % of frames so that one stray frame does not set it (a swing of amplitude A gives 2A·sin(0.45π) ≈ 1.98 A).
    NaN for a landmark never known."""
    positions = np.asarray(positions, dtype=np.float64)
    known = _known(positions)
    result = np.full(positions.shape[1:], np.nan)
    for j in range(positions.shape[1]):
        if known[:, j].any():
            low, high = np.percentile(positions[known[:, j], j], percentiles, axis=0)
            result[j] = high - low
    return result


def range_of_motion(positions: np.ndarray, percentiles: tuple[float, float] = PERCENTILES) -> np.ndarray:
    """[L] metres: each landmark's range of motion, the largest over the three axes of its percentile spread
    (:func:`range_of_motion_axes`). NaN for a landmark never known."""
    axes = range_of_motion_axes(positions, percentiles)
    result = np.full(axes.shape[0], np.nan)
    seen = np.isfinite(axes).all(axis=1)
    result[seen] = axes[seen].max(axis=1)
    return result


# --------------------------------------------------------------------------------------------------
# Frequency


def frame_rate(times: np.ndarray) -> float:
    """Frames per second: one over the median time between frames (NaN for fewer than two frames)."""
    times = np.asarray(times, dtype=np.float64)
    return float(1.0 / np.median(np.diff(times))) if len(times) > 1 else float("nan")


def speed_spectrum(times: np.ndarray, track: np.ndarray, smoothing_window: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(frequencies Hz, power) of one landmark's speed — how much of its speeding up and slowing down happens
    at each rhythm. ``track`` is [T, 3]. The speed between the first and last known frames is taken, its inner
    gaps filled by straight lines, its mean removed, and its spectrum estimated by Welch's method (averaging
    Hann-windowed segments of up to ``MAX_SEGMENT`` frames; a shorter recording is one segment). Frequencies
    run from 0.1 Hz to the Nyquist frequency (half the frame rate). Empty arrays with fewer than
    ``MIN_SPECTRUM_FRAMES`` known frames; all-zero power for a constant speed (steady drift or no movement).

    The frequency resolution is the frame rate over the segment length: a 30-frame recording at 30 fps
    resolves only 1 Hz steps, so its dominant frequency and centroid are coarse; 3 s at 30 fps gives 0.33 Hz."""
    from scipy.signal import welch

    times = np.asarray(times, dtype=np.float64)
    series = speed(times, np.asarray(track, dtype=np.float64)[:, None], smoothing_window)[:, 0]
    known = np.flatnonzero(np.isfinite(series))
    if len(known) < MIN_SPECTRUM_FRAMES:
        return np.zeros(0), np.zeros(0)
    index = np.arange(known[0], known[-1] + 1)
    series = np.interp(index, known, series[known])
    level = series.mean()
    series = series - level
    if np.abs(series).max() <= 1e-9 * abs(level):
        series[:] = 0.0  # a constant speed, up to rounding: no rhythm
    frequencies, power = welch(series, fs=frame_rate(times), nperseg=min(len(series), MAX_SEGMENT), detrend=False)
    band = frequencies >= LOW_FREQUENCY_HZ
    return frequencies[band], power[band]


def spectrum_summary(frequencies: np.ndarray, power: np.ndarray) -> tuple[float | None, float | None]:
    """(dominant frequency, spectral centroid) in Hz of a spectrum from :func:`speed_spectrum`: the frequency
    of the most power, and the power-weighted mean frequency. (None, None) for an empty or all-zero spectrum
    (a landmark that did not move, or too few frames)."""
    frequencies, power = np.asarray(frequencies, dtype=np.float64), np.asarray(power, dtype=np.float64)
    if not len(frequencies) or not np.isfinite(power).all() or power.sum() <= 0:
        return None, None
    return float(frequencies[np.argmax(power)]), float((frequencies * power).sum() / power.sum())


# --------------------------------------------------------------------------------------------------
# Left and right

_SEPARATORS = r"[\s_\-.]"


def _part(name: str) -> str:
    """A name lower-cased without spaces, underscores, hyphens or dots: "Mid Hip" and "mid_hip" are "midhip"."""
    return re.sub(_SEPARATORS, "", name).lower()


def landmark_side(name: str) -> tuple[str, str] | None:
    """(side, part) of a landmark name — side "left" or "right", part the rest lower-cased without spaces,
    underscores, hyphens or dots — or None for a name without a side. Understands "left_wrist", "Left Wrist",
    "LeftWrist", "wrist_left", "wrist.L", "l_wrist" and Pose2Sim's/OpenPose's "LWrist", "RBigToe" (a capital
    L or R directly before a capital letter)."""
    for side in ("left", "right"):
        letter = side[0]
        for pattern in (rf"^{side}{_SEPARATORS}*(.+)$", rf"^{letter}{_SEPARATORS}+(.+)$",
                        rf"^(.+?){_SEPARATORS}+(?:{side}|{letter})$"):
            match = re.match(pattern, name, flags=re.IGNORECASE)
            if match and _part(match.group(1)):
                return side, _part(match.group(1))
        match = re.match(rf"^(.+?[a-z]){side.capitalize()}$", name)  # camel case: wristLeft, WristRight
        if match:
            return side, _part(match.group(1))
    match = re.match(r"^([LR])([A-Z].*)$", name)
    if match:
        return ("left" if match.group(1) == "L" else "right"), _part(match.group(2))
    return None


def limb_pairs(names: tuple[str, ...] | list[str]) -> list[tuple[str, str]]:
    """(left name, right name) of every landmark that has a counterpart of the same part on the other side
    (LWrist with RWrist, left_knee with right_knee), in the order the left ones come in ``names``."""
    sides: dict[tuple[str, str], str] = {}
    for name in names:
        found = landmark_side(name)
        if found and found not in sides:
            sides[found] = name
    return [(sides[("left", part)], sides[("right", part)]) for side, part in sides if side == "left" and ("right", part) in sides]


def limb_landmarks(names: tuple[str, ...] | list[str]) -> dict[str, str]:
    """The landmark that stands for each of "left hand", "right hand", "left foot", "right foot", for plotting
    where the hands and feet went: the wrist for a hand (else a landmark named hand); the ankle for a foot,
    else the heel, else the big toe (else one named foot or toe). Limbs without one are left out; the keys
    come in that order."""
    preferences = {"hand": ("wrist", "hand"), "foot": ("ankle", "heel", "bigtoe", "foot", "toe")}
    chosen: dict[str, tuple[int, str]] = {}
    for name in names:
        found = landmark_side(name)
        if not found:
            continue
        side, part = found
        for limb, parts in preferences.items():
            if part in parts:
                key, rank = f"{side} {limb}", parts.index(part)
                if key not in chosen or rank < chosen[key][0]:
                    chosen[key] = (rank, name)
    order = ("left hand", "right hand", "left foot", "right foot")
    return {key: chosen[key][1] for key in order if key in chosen}




# --------------------------------------------------------------------------------------------------
# Joint angles

#: Side-less landmark parts (as :func:`_part` spells them) standing for the top and the bottom of the trunk,
#: in order of preference: OpenPose's Neck and MidHip, HALPE's Hip, the synthetic infant's neck and waist.
#: Without one, the midpoint of the two shoulders (top) or of the two hips (bottom) stands for it.
TRUNK_TOP = ("neck", "thorax")
TRUNK_BOTTOM = ("midhip", "hip", "pelvis", "waist")


class MissingLandmark(LookupError):
    """A landmark a joint angle needs is not among the recording's names: the angle is left out, never guessed."""


@attrs.frozen
class Body:
    """The landmarks of a recording found by body part, whatever the naming style (:func:`landmark_side`):
    ``names`` [L] and ``positions`` [T, L, 3] metres."""

    names: tuple[str, ...]
    positions: np.ndarray

    def joint(self, side: str, part: str) -> np.ndarray:
        """[T, 3] the landmark of ``part`` ("knee", "wrist", …) on ``side``; :class:`MissingLandmark` if none."""
        for j, name in enumerate(self.names):
            if landmark_side(name) == (side, part):
                return self.positions[:, j]
        raise MissingLandmark(f"no {side} {part} among the landmarks")

    def _middle(self, parts: tuple[str, ...], pair: str) -> np.ndarray:
        for wanted in parts:
            for j, name in enumerate(self.names):
                if landmark_side(name) is None and _part(name) == wanted:
                    return self.positions[:, j]
        try:
            return (self.joint("left", pair) + self.joint("right", pair)) / 2
        except MissingLandmark:
            raise MissingLandmark(f"no {' or '.join(parts)} landmark nor both {pair}s") from None

    def trunk(self) -> np.ndarray:
        """[T, 3] the trunk's direction, from its top (neck, or between the shoulders) down to its bottom (mid-hip,
        or between the hips)."""
        return self._middle(TRUNK_BOTTOM, "hip") - self._middle(TRUNK_TOP, "shoulder")


def segment_angle(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """[T] degrees between two segments' directions (each [T, 3]): 0 when they point the same way, 180 when
    opposite; NaN where either is unknown or has no length. Taken as atan2(|a × b|, a · b), which stays exact
    near 0° and 180°, where the arccosine of the dot product loses precision."""
    first, second = np.asarray(first, dtype=np.float64), np.asarray(second, dtype=np.float64)
    angle = np.degrees(np.arctan2(np.linalg.norm(np.cross(first, second), axis=-1), np.sum(first * second, axis=-1)))
    angle[(np.linalg.norm(first, axis=-1) == 0) | (np.linalg.norm(second, axis=-1) == 0)] = np.nan
    return angle


def flexion(proximal: np.ndarray, joint: np.ndarray, distal: np.ndarray) -> np.ndarray:
    """[T] degrees a three-point chain bends at ``joint``: the angle between the segment proximal → joint and
    the segment joint → distal, so a straight limb is 0°."""
    return segment_angle(joint - proximal, distal - joint)


def knee_flexion(body: Body, side: str) -> np.ndarray:
    """[T] degrees: the thigh (hip → knee) against the shank (knee → ankle)."""
    return flexion(body.joint(side, "hip"), body.joint(side, "knee"), body.joint(side, "ankle"))


def elbow_flexion(body: Body, side: str) -> np.ndarray:
    """[T] degrees: the upper arm (shoulder → elbow) against the forearm (elbow → wrist)."""
    return flexion(body.joint(side, "shoulder"), body.joint(side, "elbow"), body.joint(side, "wrist"))


def hip_flexion(body: Body, side: str) -> np.ndarray:
    """[T] degrees: the trunk (top → bottom, :meth:`Body.trunk`) against the thigh (hip → knee)."""
    return segment_angle(body.trunk(), body.joint(side, "knee") - body.joint(side, "hip"))


def shoulder_flexion(body: Body, side: str) -> np.ndarray:
    """[T] degrees: the trunk (top → bottom, :meth:`Body.trunk`) against the upper arm (shoulder → elbow)."""
    return segment_angle(body.trunk(), body.joint(side, "elbow") - body.joint(side, "shoulder"))


def angle_range(angles: np.ndarray) -> dict[str, Any]:
    """The extremes of one joint angle over a recording (``angles`` [T] degrees, NaN where unknown):
    ``min_deg``, ``max_deg``, ``range_deg`` (max − min: the range of motion) and ``frames``, the frames where
    it is known; the values are None when it is known at none."""
    angles = np.asarray(angles, dtype=np.float64)
    known = angles[np.isfinite(angles)]
    if not known.size:
        return {"min_deg": None, "max_deg": None, "range_deg": None, "frames": 0}
    return {"min_deg": _number(known.min()), "max_deg": _number(known.max()), "range_deg": _number(known.max() - known.min()),
            "frames": int(known.size)}


# --------------------------------------------------------------------------------------------------
# The table of measures


@attrs.frozen
class Motion:
    """A recording ready to be measured: ``names`` [L], ``times`` [T] s, ``positions`` [T, L, 3] m (smoothed
    as asked) and their ``speeds`` [T, L] m/s (:func:`speed`)."""

    names: tuple[str, ...]
    times: np.ndarray
    positions: np.ndarray
    speeds: np.ndarray

    @classmethod
    def of(cls, names: Sequence[str], times: np.ndarray, positions: np.ndarray, smoothing_window: int = 0) -> Motion:
        """The recording with its positions smoothed by ``smoothing_window`` (:func:`smooth_positions`)."""
        times = np.asarray(times, dtype=np.float64)
        positions = smooth_positions(positions, smoothing_window)
        return cls(tuple(names), times, positions, speed(times, positions))


@attrs.frozen
class Measure:
    """One named measure: ``function`` computes it, ``unit`` is its values' unit ("" for a ratio), ``label``
    the report's column heading and ``sentence`` one plain sentence on what it is, printed beside the numbers."""

    function: Callable[..., Any]
    unit: str
    label: str
    sentence: str


def _spectrum_measure(which: int) -> Callable[[Motion], np.ndarray]:
    """[L] the dominant frequency (``which`` 0) or the spectral centroid (1) of each landmark's speed."""
    def measure(motion: Motion) -> np.ndarray:
        values = [spectrum_summary(*speed_spectrum(motion.times, motion.positions[:, j]))[which] for j in range(len(motion.names))]
        return np.array([np.nan if value is None else value for value in values])

    return measure


def _correlation(motion: Motion, i: int, j: int) -> float | None:
    a, b = motion.speeds[:, i], motion.speeds[:, j]
    both = np.isfinite(a) & np.isfinite(b)
    if both.sum() < MIN_FRAMES or np.ptp(a[both]) == 0 or np.ptp(b[both]) == 0:
        return None
    value = float(np.corrcoef(a[both], b[both])[0, 1])
    return value if np.isfinite(value) else None


def _path_length_ratio(motion: Motion, i: int, j: int) -> float | None:
    enough = np.isfinite(motion.speeds[:, [i, j]]).sum(axis=0) >= MIN_FRAMES
    left, right = path_length(motion.positions[:, [i, j]])
    return float(left / right) if enough.all() and right > 0 else None


#: Per landmark: ``function(motion)`` gives [L] values (or [L, 3], one per axis), NaN where not measurable.
#: All are None for a landmark known at fewer than ``MIN_FRAMES`` frames. The report shows them in this order.
LANDMARK_MEASURES: dict[str, Measure] = {
    "mean_speed_m_s": Measure(lambda motion: mean_speed(motion.speeds), "m/s", "mean speed",
                              "The average speed of the body part over the frames where it was seen."),
    "peak_speed_m_s": Measure(lambda motion: peak_speed(motion.speeds), "m/s", "peak speed",
                              "The speed the body part reached in its fastest 5 % of moments (the 95th percentile), so that one glitch does not set it."),
    "path_length_m": Measure(lambda motion: path_length(motion.positions), "m", "path",
                             "The total distance the body part travelled along its path, adding up the steps between consecutive frames where it was seen."),
    "range_of_motion_m": Measure(lambda motion: range_of_motion(motion.positions), "m", "range",
                                 "How far apart the body part's extreme positions were: along each axis the spread between its 5th and 95th "
                                 "percentile positions, and the largest of the three."),
    "range_of_motion_xyz_m": Measure(lambda motion: range_of_motion_axes(motion.positions), "m", "range x / y / z",
                                     "The same spread of the body part's positions along each axis of the calibration separately (x, y, z)."),
    "dominant_frequency_hz": Measure(_spectrum_measure(0), "Hz", "rhythm",
                                     "The rhythm with the most power in the body part's speed, in cycles per second: a limb swinging back and forth "
                                     "f times a second speeds up twice per swing, so its speed peaks at 2f; coarse for short recordings."),
    "spectral_centroid_hz": Measure(_spectrum_measure(1), "Hz", "centroid",
                                    "The average frequency of the body part's speed, weighted by power: higher for quicker, more fidgety movement."),
}
#: Per left/right pair of :func:`limb_pairs`: ``function(motion, left index, right index)`` gives a number or None.
PAIR_MEASURES: dict[str, Measure] = {
    "speed_correlation": Measure(_correlation, "", "speed correlation",
                                 "How alike the left and right sides moved in time: the correlation of their speeds, 1 when they speed up and "
                                 "slow down together, near 0 when unrelated, negative when one moves while the other rests."),
    "path_length_ratio": Measure(_path_length_ratio, "", "path length ratio",
                                 "How far the left side travelled compared with the right: 1 when both travelled as far, above 1 when the left "
                                 "travelled farther."),
}
#: Per side and frame: ``function(body, side)`` gives [T] degrees, raising :class:`MissingLandmark` when a
#: landmark it needs is absent. Flexion is 0° for a straight limb (or a limb in line with the trunk).
JOINT_ANGLES: dict[str, Measure] = {
    "knee_flexion": Measure(knee_flexion, "deg", "knee flexion",
                            "How far the knee bends: the angle between the thigh (hip to knee) and the shank (knee to ankle), 0° with the leg straight."),
    "elbow_flexion": Measure(elbow_flexion, "deg", "elbow flexion",
                             "How far the elbow bends: the angle between the upper arm (shoulder to elbow) and the forearm (elbow to wrist), "
                             "0° with the arm straight."),
    "hip_flexion": Measure(hip_flexion, "deg", "hip flexion",
                           "How far the thigh is raised from the line of the trunk (neck to mid-hip): 0° with the leg in line with the trunk; "
                           "measured in 3D, so spreading the legs apart (abduction) adds to it."),
    "shoulder_flexion": Measure(shoulder_flexion, "deg", "shoulder flexion",
                                "How far the upper arm is raised from the trunk (neck to mid-hip): 0° with the arm along the side; measured in 3D, "
                                "so raising the arm sideways (abduction) adds to it."),
}
SIDES = ("left", "right")


def limb_symmetry(names: Sequence[str], times: np.ndarray, positions: np.ndarray, smoothing_window: int = 0) -> list[dict[str, Any]]:
    """How alike the two sides moved, per left/right pair of :func:`limb_pairs`: each of :data:`PAIR_MEASURES`
    — ``speed_correlation``, the Pearson correlation of the two speeds over the frames where both are known (None
    with fewer than ``MIN_FRAMES`` such frames or when one side never changes speed), and ``path_length_ratio``,
    the left's path length over the right's (None when either is known at fewer than ``MIN_FRAMES`` frames or
    the right did not move). Each entry also names ``left``, ``right`` and the ``part``."""
    return _pairs(Motion.of(names, times, positions, smoothing_window))


def _pairs(motion: Motion) -> list[dict[str, Any]]:
    names = list(motion.names)
    return [{"left": left, "right": right, "part": landmark_side(left)[1],
             **{key: _number(measure.function(motion, names.index(left), names.index(right))) for key, measure in PAIR_MEASURES.items()}}
            for left, right in limb_pairs(names)]


def joint_angles(names: Sequence[str], positions: np.ndarray) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """({"left_knee_flexion": [T] degrees, …}, {angle: why it is left out}) for every entry of
    :data:`JOINT_ANGLES` on each side; an angle whose landmarks are absent is left out, with the reason."""
    body = Body(tuple(names), np.asarray(positions, dtype=np.float64))
    angles, left_out = {}, {}
    for key, measure in JOINT_ANGLES.items():
        for side in SIDES:
            try:
                angles[f"{side}_{key}"] = measure.function(body, side)
            except MissingLandmark as missing:
                left_out[f"{side}_{key}"] = str(missing)
    return angles, left_out


def joint_angle_accuracy(names: Sequence[str], carried: np.ndarray, reference: np.ndarray, bound_from: int = 1) -> dict[str, Any] | None:
    """How far the joint angles of the ``carried`` landmarks are from those of the ``reference`` (both [T, L, 3],
    the same ``names``; the reference is the source's own landmarks at the same frames) after the first
    ``bound_from`` frames (those the landmarks were bound from), where both are known: ``median_deg`` and ``p90_deg`` of the
    absolute difference over every (frame, angle) pair, their count ``pairs``, and ``per_angle_median_deg``. None when no
    angle is known in both."""
    mine, _ = joint_angles(names, carried)
    theirs, _ = joint_angles(names, reference)
    errors = {key: np.abs(mine[key][bound_from:] - theirs[key][bound_from:]) for key in mine}
    errors = {key: error[np.isfinite(error)] for key, error in errors.items()}
    pooled = np.concatenate([np.zeros(0), *errors.values()])
    if not pooled.size:
        return None
    return {"median_deg": _number(np.median(pooled)), "p90_deg": _number(np.percentile(pooled, 90)), "pairs": int(pooled.size),
            "per_angle_median_deg": {key: _number(np.median(error)) if error.size else None for key, error in errors.items()}}


# --------------------------------------------------------------------------------------------------
# Everything together


def _number(value: Any) -> Any:
    """A JSON-ready value: a float rounded to 1e-6 (None for NaN or None), a list for an array."""
    if isinstance(value, np.ndarray):
        return [_number(item) for item in value]
    return round(float(value), 6) if value is not None and np.isfinite(value) else None


def movement_summary(names: Sequence[str], times: np.ndarray, positions: np.ndarray, smoothing_window: int = 0) -> dict[str, Any]:
    """Every measure of the tables for a recording, ready for ``json.dumps`` (plain floats, None where a
    measure cannot be given, never NaN):

    - ``landmarks``: {name: {measure: value}} with the keys of :data:`LANDMARK_MEASURES` (all None for a
      landmark known at fewer than ``MIN_FRAMES`` frames);
    - ``pairs``: [{left, right, part, *PAIR_MEASURES}] (:func:`limb_symmetry`);
    - ``joint_angles``: {"left_knee_flexion": {min_deg, max_deg, range_deg, frames, per_frame_deg}} for every
      entry of :data:`JOINT_ANGLES` on each side whose landmarks exist (:func:`angle_range`; ``per_frame_deg``
      the angle at every frame, None where unknown), and ``joint_angles_left_out``: {angle: why};
    - ``measures``: {key: {unit, label, sentence}} of every table entry, so the file explains itself;
    - ``duration_s``, ``frame_rate_hz``, ``frames``, and ``frequency_resolution_hz``, the spacing of the
      spectrum's frequencies over the whole recording (how coarse the frequencies are);
    - ``smoothing_window``, the Savitzky–Golay window the positions were smoothed by (0: none)."""
    motion = Motion.of(names, times, positions, smoothing_window)
    enough = np.isfinite(motion.speeds).sum(axis=0) >= MIN_FRAMES
    values = {key: measure.function(motion) for key, measure in LANDMARK_MEASURES.items()}
    landmarks = {name: {key: _number(values[key][j]) if enough[j] else None for key in LANDMARK_MEASURES} for j, name in enumerate(motion.names)}
    angles, left_out = joint_angles(motion.names, motion.positions)
    times = motion.times
    rate = frame_rate(times)
    return {"landmarks": landmarks, "pairs": _pairs(motion),
            "joint_angles": {key: {**angle_range(series), "per_frame_deg": _number(series)} for key, series in angles.items()},
            "joint_angles_left_out": left_out,
            "measures": {key: {"unit": measure.unit, "label": measure.label, "sentence": measure.sentence}
                         for table in (LANDMARK_MEASURES, PAIR_MEASURES, JOINT_ANGLES) for key, measure in table.items()},
            "duration_s": _number(times[-1] - times[0]) if len(times) else None, "frame_rate_hz": _number(rate), "frames": int(len(times)),
            "frequency_resolution_hz": _number(rate / min(len(times), MAX_SEGMENT)) if len(times) >= MIN_SPECTRUM_FRAMES else None,
            "smoothing_window": int(smoothing_window)}


def movement_rows(summary: dict[str, Any]) -> list[tuple[str, str, float | None, str]]:
    """The scalars of a :func:`movement_summary` as (subject, measure, value, unit) rows for a CSV — one row
    per landmark and measure (``range_of_motion_xyz_m:x`` for an axis), per pair ("LWrist/RWrist") and measure,
    and per joint angle and extreme (``min_deg``, ``max_deg``, ``range_deg``); None where unknown."""
    units = {key: entry["unit"] for key, entry in summary["measures"].items()}
    rows: list[tuple[str, str, float | None, str]] = []
    for name, values in summary["landmarks"].items():
        for key, value in values.items():
            if key.endswith("_xyz_m"):
                rows += [(name, f"{key}:{axis}", item, units[key]) for axis, item in zip("xyz", value or [None] * 3, strict=True)]
            else:
                rows.append((name, key, value, units[key]))
    for pair in summary["pairs"]:
        rows += [(f"{pair['left']}/{pair['right']}", key, pair[key], units[key]) for key in PAIR_MEASURES]
    for angle, extremes in summary["joint_angles"].items():
        rows += [(angle, key, extremes[key], "deg") for key in ("min_deg", "max_deg", "range_deg")]
    return rows
