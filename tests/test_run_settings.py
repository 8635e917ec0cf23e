"""``mmcsplat run``'s settings: bad tracking values and reader options fail before the first step, naming
the value, and leave nothing behind; the reader's options reach the ingest."""

from __future__ import annotations

from pathlib import Path

import pytest

from mmcsplat.configuration.config import load_config
from mmcsplat.configuration.registry import default_registry
from mmcsplat.jobs.capture import DEFAULT_CONFIG, TRACK_MEANS_LR, CaptureSettings, guidance_overrides, run_capture
from mmcsplat.pipeline.track import dynamics_choice
from mmcsplat.plugin_api.errors import InputError, MmcsplatError


@pytest.mark.parametrize(("settings", "message"), [
    (CaptureSettings(track_flow_gain=0), "flow_gain must be > 0, got 0"),
    (CaptureSettings(track_iterations=-1), "iterations must be ≥ 0, got -1"),
    (CaptureSettings(overrides=("dynamics.lambda_rigid=-1",)), "lambda_rigid must be ≥ 0"),
    (CaptureSettings(track_keypoints=1), "--track-keypoints: .*capture has no 2D keypoints to guide the tracking with"),
    (CaptureSettings(cameras=("cam_01",)), r"--cameras cam_01 with --holdout \(none\) leaves 1 camera\(s\) .*a fit needs two"),
    (CaptureSettings(cameras=("a", "b"), holdout=("b",)), r"--cameras a,b with --holdout b leaves 1 camera\(s\) to train on \(a\)"),
])
def test_bad_tracking_values_fail_before_the_first_step(tmp_path, settings, message):
    capture, out = tmp_path / "capture", tmp_path / "out"
    capture.mkdir()
    with pytest.raises(InputError, match=message):
        run_capture(capture, out, settings, progress=False, log=lambda line: None)
    assert not out.exists()


@pytest.mark.parametrize("source", [
    {"name": "openpose", "folder": 'C:\\rig "2"\\pose_2d'},
    {"name": "sleap", "files": ["/data/a b.slp", "/data/c.analysis.h5"]},
])
def test_keypoint_guidance_reaches_the_tracking_with_the_capture_keypoints(tmp_path, source):
    overrides = guidance_overrides(0.5, source, tmp_path)
    dynamics = dynamics_choice(load_config(DEFAULT_CONFIG, overrides), "iterative").build()
    assert dynamics.lambda_keypoints == 0.5
    assert dynamics.keypoints == source


def test_reader_options_reach_the_ingest(tmp_path, monkeypatch):
    class Stop(Exception):
        """Ends the run at its ingest."""

    seen = {}

    def ingest(*args, **kwargs):
        seen.update(kwargs)
        raise Stop

    monkeypatch.setattr("mmcsplat.pipeline.ingest.ingest", ingest)
    monkeypatch.setattr("mmcsplat.pipeline.ingest.capture_reader", lambda *args, **kwargs: None)  # the folder below is empty
    capture = tmp_path / "capture"
    capture.mkdir()
    settings = CaptureSettings(reader_options=("size_mismatch=crop", "camera_map=order"))
    with pytest.raises(Stop):
        run_capture(capture, tmp_path / "out", settings, progress=False, log=lambda line: None)
    assert seen["reader_options"] == {"size_mismatch": "crop", "camera_map": "order"}


DEMO = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "pose2sim_demo"


@pytest.mark.skipif(not DEMO.is_dir(), reason="needs ../shared/data/pose2sim_demo")
@pytest.mark.parametrize(("options", "message"), [
    (("size_mismatch=nonsense",), "size_mismatch must be one of"),
    (("nosuch=1",), "unknown parameter"),
    (("size_mismatch",), "--reader-set: 'size_mismatch' must look like key.path=value"),
])
def test_bad_reader_options_fail_before_anything_is_written(tmp_path, options, message):
    out = tmp_path / "out"
    with pytest.raises(InputError, match=message):
        run_capture(DEMO, out, CaptureSettings(reader_options=options), progress=False, log=lambda line: None)
    assert not out.exists()


@pytest.mark.skipif(not DEMO.is_dir(), reason="needs ../shared/data/pose2sim_demo")
@pytest.mark.parametrize(("settings", "message"), [
    (CaptureSettings(), "several calibration files"),
    (CaptureSettings(calibration=str(DEMO / "Calib_qualisys.toml"), frames=(5, 3, None)), "select none of the 100 frames"),
])
def test_a_capture_refused_at_its_ingest_leaves_no_folder(tmp_path, settings, message):
    out = tmp_path / "out"
    with pytest.raises(InputError, match=message):
        run_capture(DEMO, out, settings, progress=False, log=lambda line: None)
    assert not out.exists()


@pytest.mark.skipif(not DEMO.is_dir(), reason="needs ../shared/data/pose2sim_demo")
def test_a_session_that_fails_half_made_leaves_no_partial_and_names_the_session(tmp_path):
    out = tmp_path / "out"
    settings = CaptureSettings(calibration=str(DEMO / "Calib_qualisys.toml"), frames=(0, 1, None), scale=0.125)
    with pytest.raises(InputError, match=rf"session {out / 'session.zarr'}: camera 'cam_01' has 1 frame\(s\)"):
        run_capture(DEMO, out, settings, progress=False, log=lambda line: None)
    assert not out.exists()  # nor a hidden .session.zarr.partial in it


@pytest.mark.parametrize(("backend", "message"), [
    ("no-such-renderer", "no-such-renderer"),
    ("torch-cuda", "torch-cuda.*not usable here"),
])
def test_a_backend_that_cannot_run_here_fails_before_the_first_step(tmp_path, backend, message):
    if backend == "torch-cuda" and default_registry().get("renderer", backend).unavailable_reason() is None:
        pytest.skip("torch-cuda runs here (gsplat and a CUDA device)")
    capture, out = tmp_path / "capture", tmp_path / "out"
    capture.mkdir()
    with pytest.raises(MmcsplatError, match=message):
        run_capture(capture, out, CaptureSettings(backend=backend), progress=False, log=lambda line: None)
    assert not out.exists()


def test_the_fit_gets_the_backend_and_the_tracking_settings(tmp_path, monkeypatch):
    class Stop(Exception):
        """Ends the run at its fit."""

    seen = {}

    def fit(session, config, run, backend=None, **kwargs):
        seen.update(backend=backend, dynamics=config.values["dynamics"])
        raise Stop

    monkeypatch.setattr("mmcsplat.pipeline.fit.FirstFrameFit", fit)
    monkeypatch.setattr("mmcsplat.storage.session.SessionReader", lambda path: None)
    capture, out = tmp_path / "capture", tmp_path / "out"
    capture.mkdir()
    (out / "session.zarr").mkdir(parents=True)  # ingested already: the run goes straight to the fit
    with pytest.raises(Stop):
        run_capture(capture, out, CaptureSettings(backend="torch-reference", track_iterations=7, track_flow_gain=1.5), progress=False,
                    log=lambda line: None)
    assert seen["backend"] == "torch-reference"
    # recorded in run.json with the fit, so that `mmcsplat track RUN` tracks as the run does
    assert seen["dynamics"] == {"name": "iterative", "iterations": 7, "means_lr": TRACK_MEANS_LR, "flow_gain": 1.5}
