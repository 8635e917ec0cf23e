"""``mmcsplat run`` checks its settings before its first step: bad tracking values fail at once, naming
the value, and leave nothing behind."""

from __future__ import annotations

import pytest

from mmcsplat.jobs.capture import CaptureSettings, run_capture
from mmcsplat.plugin_api.errors import InputError


@pytest.mark.parametrize(("settings", "message"), [
    (CaptureSettings(track_flow_gain=0), "flow_gain must be > 0, got 0"),
    (CaptureSettings(track_iterations=-1), "iterations must be ≥ 0, got -1"),
    (CaptureSettings(overrides=("dynamics.lambda_rigid=-1",)), "lambda_rigid must be ≥ 0"),
])
def test_bad_tracking_values_fail_before_the_first_step(tmp_path, settings, message):
    capture, out = tmp_path / "capture", tmp_path / "out"
    capture.mkdir()
    with pytest.raises(InputError, match=message):
        run_capture(capture, out, settings, progress=False, log=lambda line: None)
    assert not out.exists()
