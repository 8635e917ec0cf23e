"""The steps a tracker spends on a frame: a number kept as it is, or ``auto`` from the frame rate."""

from __future__ import annotations

import pytest

from mmcsplat.training.frame_steps import checked_steps, steps_per_frame


@pytest.mark.parametrize(("fps", "steps"), [(60, 50), (120, 50), (30, 100), (25, 120), (29.97, 101), (10, 300)])
def test_auto_gives_a_second_of_video_the_same_steps_and_a_frame_fifty_at_least(fps, steps):
    assert steps_per_frame("auto", fps) == steps
    assert steps_per_frame(7, fps) == 7  # a number is kept whatever the frame rate
    assert steps_per_frame(0, fps) == 0


@pytest.mark.parametrize("value", [-1, "many", 2.5, True, None])
def test_anything_else_is_refused(value):
    for check in (lambda: steps_per_frame(value, 30.0), lambda: checked_steps(value)):
        with pytest.raises(ValueError, match="steps a frame must be a whole number ≥ 0 or 'auto'"):
            check()


@pytest.mark.parametrize("value", ["auto", 0, 7])
def test_a_setting_is_checked_without_a_frame_rate(value):
    assert checked_steps(value) == value
