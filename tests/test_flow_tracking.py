"""Flow-guided prediction in the iterative dynamics: with the session's flow, a frame starts where the
images say the subject went; without flow, or asked to, at constant velocity."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fitting_scene import moved, subject, write_fitted_run, write_flow_session, write_session

from mmcsplat.cli import main
from mmcsplat.pipeline.track import TRACK_INFO
from mmcsplat.storage.tracks import TrackReader

TRUTH = subject(count=60, scale=0.02)
FRAMES = 2


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("flow-tracking")
    return root, write_flow_session(root / "scene.zarr", FRAMES, TRUTH)


def predicted_only(root, session, name, *settings):
    """Track with no fitting at all (0 iterations): the tracks are the predictions themselves."""
    run = write_fitted_run(root / name, session, TRUTH)
    assert main(["track", str(run), "--dynamics", "iterative", "--no-progress", "--set", "dynamics.iterations=0", *settings]) == 0
    return run


def test_flow_prediction_follows_the_subject_where_constant_velocity_cannot(scene):
    root, session = scene
    flow_run = predicted_only(root, session, "flow")
    still_run = predicted_only(root, session, "still", "--set", "dynamics.predict=constant-velocity")
    info = json.loads((flow_run / TRACK_INFO).read_text())["summary"]
    assert info["prediction"] == "flow" and len(info["flow_fallback_gaussians"]) == FRAMES - 1
    assert json.loads((still_run / TRACK_INFO).read_text())["summary"]["prediction"] == "constant-velocity"
    truth = moved(TRUTH, 1).means.numpy()
    flow_error = np.median(np.linalg.norm(TrackReader(flow_run).means(1) - truth, axis=1))
    still_error = np.median(np.linalg.norm(TrackReader(still_run).means(1) - truth, axis=1))  # no velocity yet at frame 1
    assert flow_error < 0.5 * still_error, (flow_error, still_error)


def test_without_flow_the_prediction_is_constant_velocity_and_says_so(tmp_path, caplog):
    session = write_session(tmp_path / "scene.zarr", frames=2, truth=TRUTH)
    run = write_fitted_run(tmp_path / "run", session, TRUTH)
    assert main(["track", str(run), "--dynamics", "iterative", "--no-progress", "--set", "dynamics.iterations=0"]) == 0
    assert json.loads((run / TRACK_INFO).read_text())["summary"]["prediction"] == "constant-velocity"
    assert any("no optical flow" in record.getMessage() and "mmcsplat flow" in record.getMessage() for record in caplog.records)
