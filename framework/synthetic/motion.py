"""Spontaneous infant movement: every joint turns smoothly by a seeded sum of sinusoids.

Each joint axis swings within a range of angles (radians, about the axes of the part's rest frame) by two
sinusoids of random frequency in 0.3–2 Hz and random phase; the faster component gets the smaller share,
so limbs move at plausible speeds (hands and feet travel centimetres to about a decimetre). Ranges are
one-sided where the other side would push a limb into the mat.

Two variants test what the natural motion rarely shows: ``still-trunk`` holds the torso, pelvis and head
in one pose for the whole sequence (only the limbs move: an infant lying on a mat, whose trunk a temporal
median keeps in the "background"), and ``fast-kicks`` swings both legs in quick kicks, the feet moving
about their own width between frames at 30 fps (a limb that leaves its last position, for tracking).
"""

from __future__ import annotations

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.synthetic.body import Part

#: Angle range (lo, hi) per rest-frame axis (x: along the limb — a twist; y, z: swings) by part-name
#: prefix. x/y/z follow :func:`mmcsplat.synthetic.body.infant_parts`' frames (z is "up").
RANGES: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    "torso": ((-0.06, 0.06), (0.0, 0.0), (-0.04, 0.04)),  # small roll and yaw
    "pelvis": ((-0.05, 0.05), (0.0, 0.0), (-0.03, 0.03)),
    "head": ((-0.5, 0.5), (-0.12, 0.05), (-0.08, 0.08)),  # turning left and right, slight nodding
    "upper_arm": ((-0.25, 0.25), (-0.45, 0.05), (-0.3, 0.3)),  # y < 0 lifts the arm off the mat
    "lower_arm": ((-0.3, 0.3), (-0.4, 0.2), (-0.25, 0.25)),
    "hand": ((-0.4, 0.4), (-0.3, 0.3), (-0.3, 0.3)),
    "thigh": ((-0.15, 0.15), (-0.35, 0.1), (-0.2, 0.2)),  # kicking: y < 0 raises the knee
    "shank": ((-0.1, 0.1), (-0.45, 0.15), (-0.1, 0.1)),  # y < 0 stretches the knee
    "foot": ((-0.2, 0.2), (-0.3, 0.3), (-0.15, 0.15)),
}

FREQUENCY_RANGE = (0.3, 2.0)  # Hz

#: The motion variants :meth:`Motion.random` draws (module docstring).
MOTIONS = ("natural", "still-trunk", "fast-kicks")
#: Parts ``still-trunk`` holds still.
TRUNK = ("torso", "pelvis", "head")
#: ``fast-kicks``: the hip's and knee's flexion ranges (rest-frame y, y < 0 raises the knee / stretches
#: it) and the kicks' frequency range. Peaks of 1–1.7 m/s at the foot: about its 5 cm width per frame at
#: 30 fps, as fast as a real infant's kicks.
KICK_RANGES = {"thigh": (-0.7, 0.1), "shank": (-0.8, 0.2)}
KICK_FREQUENCY = (2.0, 2.6)  # Hz


@attrs.frozen(eq=False)
class Motion:
    """Per part and axis: the angle range centre ``middle`` [P, 3] and half-width ``half`` [P, 3], and two
    sinusoids each (``frequency``, ``phase``, ``weight``: [P, 3, 2], weights summing to 1)."""

    middle: np.ndarray
    half: np.ndarray
    frequency: np.ndarray
    phase: np.ndarray
    weight: np.ndarray

    @classmethod
    def random(cls, parts: tuple[Part, ...], rng: np.random.Generator, kind: str = "natural") -> Motion:
        """Draw a motion of variant ``kind`` (one of :data:`MOTIONS`) for ``parts``; amplitudes 60–100 % of
        each axis' range. Every variant draws the same random numbers, so a seed gives the same arms (and,
        but for ``fast-kicks``, legs) in each."""
        if kind not in MOTIONS:
            raise InputError(f"motion must be one of {', '.join(MOTIONS)}, got {kind!r}")
        prefixes = [next(key for key in RANGES if part.name.startswith(key)) for part in parts]
        ranges = np.array([RANGES[prefix] for prefix in prefixes])
        lo, hi = ranges[..., 0], ranges[..., 1]
        scale = rng.uniform(0.6, 1.0, size=lo.shape)
        frequency = rng.uniform(*FREQUENCY_RANGE, size=lo.shape + (2,))
        phase = rng.uniform(0, 2 * np.pi, size=lo.shape + (2,))
        weight = 1 / frequency
        weight /= weight.sum(axis=-1, keepdims=True)
        middle, half = (lo + hi) / 2, (hi - lo) / 2 * scale
        if kind == "still-trunk":
            half[[prefix in TRUNK for prefix in prefixes]] = 0.0
        elif kind == "fast-kicks":
            # One rate and phase per leg, shared by its hip and knee (they kick together); the legs kick out of step.
            rates, starts = rng.uniform(*KICK_FREQUENCY, size=2), rng.uniform(0, 2 * np.pi, size=2)
            for i, prefix in enumerate(prefixes):
                if prefix in KICK_RANGES:
                    low, high = KICK_RANGES[prefix]
                    middle[i, 1], half[i, 1] = (low + high) / 2, (high - low) / 2
                    leg = int(parts[i].name.endswith("right"))
                    frequency[i, 1], phase[i, 1], weight[i, 1] = rates[leg], starts[leg], (1.0, 0.0)
        return cls(middle, half, frequency, phase, weight)

    def rotvecs(self, times: np.ndarray) -> np.ndarray:
        """Joint rotation vectors [T, P, 3] at ``times`` [T] seconds."""
        times = np.asarray(times, dtype=np.float64)[:, None, None, None]
        wave = np.sum(self.weight * np.sin(2 * np.pi * self.frequency * times + self.phase), axis=-1)
        return self.middle + self.half * wave
