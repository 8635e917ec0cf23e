"""How many steps a tracker spends on each frame: a number, or ``auto``, which follows the frame rate.

A frame's steps must reach a limb that moved since the last frame, and frames further apart move it
further, so ``auto`` keeps the steps per second of video fixed rather than the steps per frame. The
Pose2Sim demo at 60 fps is tracked at 50 steps a frame; its every second frame (30 fps) loses the left
leg at 50 (64.7 mm) but follows it at 100 (37.9 mm), in the same time per second of video
(docs/results.md, "Lower frame rates").
"""

from __future__ import annotations

import math

#: The setting that resolves the steps a frame from the frame rate (:func:`steps_per_frame`).
AUTO_STEPS = "auto"
#: ``auto``'s steps a second of video.
STEPS_PER_SECOND = 3000.0
#: The fewest steps a frame ``auto`` gives, whatever the frame rate: at 60 fps 30 steps lose accuracy
#: (41.7 against 35.8 mm, docs/performance.md, "Issue 27").
FEWEST_STEPS = 50


def checked_steps(value: int | str) -> int | str:
    """``value`` when it is a setting of the steps a frame (a whole number ≥ 0, or :data:`AUTO_STEPS`); any
    other raises ``ValueError``."""
    if value != AUTO_STEPS and (isinstance(value, bool) or not isinstance(value, int) or value < 0):
        raise ValueError(f"steps a frame must be a whole number ≥ 0 or {AUTO_STEPS!r}, got {value!r}")
    return value


def steps_per_frame(value: int | str, fps: float) -> int:
    """The steps a frame for the setting ``value`` on frames ``fps`` a second apart: ``value`` itself, or for
    :data:`AUTO_STEPS` :data:`STEPS_PER_SECOND` a second of video and :data:`FEWEST_STEPS` at least (50 at
    60 fps, 100 at 30, 120 at 25, 150 at 20). A value that is neither raises ``ValueError`` (:func:`checked_steps`)."""
    if checked_steps(value) == AUTO_STEPS:
        return max(FEWEST_STEPS, math.ceil(STEPS_PER_SECOND / fps - 1e-9))
    return value
