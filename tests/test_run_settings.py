"""``mmcsplat run``'s settings: bad tracking values, reader options and segmenters fail before the first
step, naming the value, and leave nothing behind; the reader's options reach the ingest, and a named
segmenter (a third party's) makes the masks."""

from __future__ import annotations

import json
import sys
import types
from pathlib import Path
from typing import ClassVar

import attrs
import numpy as np
import pytest

from mmcsplat import Registration, hookimpl
from mmcsplat.cli import main
from mmcsplat.configuration.config import load_config
from mmcsplat.configuration.registry import Registry, default_registry
from mmcsplat.jobs.capture import DEFAULT_CONFIG, TRACK_MEANS_LR, CaptureSettings, guidance_overrides, run_capture
from mmcsplat.pipeline.track import dynamics_choice
from mmcsplat.plugin_api.errors import InputError, MmcsplatError
from mmcsplat.plugin_api.interfaces import Segmenter
from mmcsplat.storage.session import SessionReader


@pytest.mark.parametrize(("settings", "message"), [
    (CaptureSettings(track_flow_gain=0), "flow_gain must be > 0, got 0"),
    (CaptureSettings(track_iterations=-1), "track_iterations: steps a frame must be a whole number ≥ 0 or 'auto', got -1"),
    (CaptureSettings(track_iterations="many"), "track_iterations: steps a frame must be a whole number ≥ 0 or 'auto', got 'many'"),
    (CaptureSettings(overrides=("dynamics.lambda_rigid=-1",)), "lambda_rigid must be ≥ 0"),
    (CaptureSettings(track_keypoints=1), "--track-keypoints: .*capture has no 2D keypoints to guide the tracking with"),
    (CaptureSettings(cameras=("cam_01",)), r"--cameras cam_01 with --holdout \(none\) leaves 1 camera\(s\) .*a fit needs two"),
    (CaptureSettings(cameras=("a", "b"), holdout=("b",)), r"--cameras a,b with --holdout b leaves 1 camera\(s\) to train on \(a\)"),
    (CaptureSettings(segmenter_options=("model=person.onnx",)), "--segmenter-set model=person.onnx without --segmenter"),
    (CaptureSettings(segmenter="background", segmenter_options=("method=guess",)), "method must be one of"),
    (CaptureSettings(keypoint_options=("camera_map=order",)), "--keypoints-set camera_map=order: .* has no 2D keypoints .*give --keypoints"),
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
    {"name": "openpose", "folder": "/rig/pose_2d", "camera_map": {"cam_01": "north", "cam 2": 'we"st'}},
    {"name": "deeplabcut", "folder": "/rig/pose-2d", "camera_map": "order"},
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
    (CaptureSettings(calibration=str(DEMO / "Calib_qualisys.toml"), frames=(200, 300, None)), "select none of the 100 frames"),
])
def test_a_capture_refused_at_its_ingest_leaves_no_folder(tmp_path, settings, message):
    out = tmp_path / "out"
    with pytest.raises(InputError, match=message):
        run_capture(DEMO, out, settings, progress=False, log=lambda line: None)
    assert not out.exists()


@pytest.mark.skipif(not DEMO.is_dir(), reason="needs ../shared/data/pose2sim_demo")
def test_a_session_that_fails_half_made_leaves_no_partial_and_names_the_session(tmp_path):
    out = tmp_path / "out"
    settings = CaptureSettings(calibration=str(DEMO / "Calib_qualisys.toml"), frames=(0, 2, None), scale=0.125)
    with pytest.raises(InputError, match=rf"session {out / 'session.zarr'}: camera 'cam_01' has 2 frame\(s\)"):
        run_capture(DEMO, out, settings, progress=False, log=lambda line: None)
    assert not out.exists()  # nor a hidden .session.zarr.partial in it


@pytest.mark.parametrize(("frames", "message"), [((0, 1, None), "--frames 0:1 selects 1 frame"), ((4, 6, 2), "--frames 4:6:2 selects 1 frame"),
                                               ((None, 0, None), "--frames :0 selects 0 frame")])
def test_fewer_than_two_frames_are_refused_before_the_capture_is_read(tmp_path, frames, message):
    capture, out = tmp_path / "capture", tmp_path / "out"
    capture.mkdir()  # empty: no reader would recognise it, so the frames are judged before any is looked for
    with pytest.raises(InputError, match=message):
        run_capture(capture, out, CaptureSettings(frames=frames), progress=False, log=lambda line: None)
    assert not out.exists()


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


@pytest.mark.parametrize(("iterations", "fps", "expected"), [(7, 30.0, 7), ("auto", 30.0, 100), ("auto", 60.0, 50)])
def test_the_fit_gets_the_backend_and_the_tracking_settings(tmp_path, monkeypatch, iterations, fps, expected):
    class Stop(Exception):
        """Ends the run at its fit."""

    seen = {}

    def fit(session, config, run, backend=None, **kwargs):
        seen.update(backend=backend, dynamics=config.values["dynamics"])
        raise Stop

    monkeypatch.setattr("mmcsplat.pipeline.fit.FirstFrameFit", fit)
    monkeypatch.setattr("mmcsplat.storage.session.SessionReader", lambda path: types.SimpleNamespace(fps=fps))
    capture, out = tmp_path / "capture", tmp_path / "out"
    capture.mkdir()
    (out / "session.zarr").mkdir(parents=True)  # ingested already: the run goes straight to the fit
    said = []
    with pytest.raises(Stop):
        run_capture(capture, out, CaptureSettings(backend="torch-reference", track_iterations=iterations, track_flow_gain=1.5),
                    progress=False, log=said.append)
    assert seen["backend"] == "torch-reference"
    # recorded in run.json with the fit, so that `mmcsplat track RUN` tracks as the run does
    assert seen["dynamics"] == {"name": "iterative", "iterations": expected, "means_lr": TRACK_MEANS_LR, "flow_gain": 1.5}
    assert any(f"tracking at {expected} steps a frame" in line for line in said) == (iterations == "auto")


def test_the_command_line_takes_auto_or_a_whole_number_of_iterations(tmp_path, capsys):
    for bad in ("-1", "1.5", "some"):
        with pytest.raises(SystemExit):
            main(["run", str(tmp_path), "--out", str(tmp_path / "out"), "--track-iterations", bad])
        assert f"expected a whole number of steps (0 or more) or 'auto', got '{bad}'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_an_unknown_segmenter_fails_before_the_first_step(tmp_path):
    capture, out = tmp_path / "capture", tmp_path / "out"
    capture.mkdir()
    with pytest.raises(MmcsplatError, match="no-such-segmenter"):
        run_capture(capture, out, CaptureSettings(segmenter="no-such-segmenter"), progress=False, log=lambda line: None)
    assert not out.exists()


@attrs.frozen
class BoxSegmenter(Segmenter):
    """A third party's segmenter: the middle ``share`` of each image's width and height is the subject."""

    share: float = 0.5
    built: ClassVar[list[float]] = []  # the shares it was built with, once per build (a model would load each time)

    def __attrs_post_init__(self):
        BoxSegmenter.built.append(self.share)

    def segment(self, session, camera):
        for t in np.flatnonzero(session.present(camera)):
            mask = np.zeros((session.camera(camera).height, session.camera(camera).width), bool)
            rows, cols = (round(size * (1 - self.share) / 2) for size in mask.shape)
            mask[rows:mask.shape[0] - rows, cols:mask.shape[1] - cols] = True
            yield int(t), mask, None


@pytest.mark.skipif(not DEMO.is_dir(), reason="needs ../shared/data/pose2sim_demo")
def test_a_named_segmenter_makes_the_masks_instead_of_the_capture_keypoints(tmp_path, monkeypatch):
    class Stop(Exception):
        """Ends the run at its fit."""

    plugin = types.ModuleType("box_plugin")
    plugin.BoxSegmenter = BoxSegmenter
    plugin.mmcsplat_segmenters = hookimpl(lambda: [Registration("box", "box_plugin:BoxSegmenter")])
    monkeypatch.setitem(sys.modules, "box_plugin", plugin)
    with_box = Registry(plugin_modules=[("box", "box-plugin", plugin)])
    for module in ("mmcsplat.configuration.config", "mmcsplat.pipeline.segment"):  # run's check before ingest, and the segmentation
        monkeypatch.setattr(f"{module}.default_registry", lambda: with_box)
    monkeypatch.setattr("mmcsplat.pipeline.fit.FirstFrameFit", lambda *args, **kwargs: (_ for _ in ()).throw(Stop()))
    out = tmp_path / "out"
    settings = CaptureSettings(calibration=str(DEMO / "Calib_qualisys.toml"), frames=(0, 3, None), scale=0.125, segmenter="box",
                               segmenter_options=("share=0.4",))
    BoxSegmenter.built.clear()
    with pytest.raises(Stop):
        run_capture(DEMO, out, settings, progress=False, log=lambda line: None)
    assert BoxSegmenter.built == [0.4]  # checked before ingest and used for the masks: one build
    choice = json.loads((out / "masks.json").read_text())
    assert choice["masks"] == "box" and "(--segmenter)" in choice["detail"]  # the capture's pose_2d would have made keypoint masks
    session = SessionReader(out / "session.zarr")
    for camera in session.camera_names:
        expected = next(BoxSegmenter(share=0.4).segment(session, camera))[1]
        assert all(np.array_equal(np.asarray(session.frame(t, camera).mask, bool), expected) for t in range(session.num_frames))
        assert session.plate(camera) is not None  # estimated around the box


def test_the_command_line_passes_the_segmenter_and_its_parameters(tmp_path, capsys):
    capture, out = tmp_path / "capture", tmp_path / "out"
    capture.mkdir()
    assert main(["run", str(capture), "--out", str(out), "--segmenter", "background", "--segmenter-set", "method=guess", "--no-progress"]) == 2
    assert "method must be one of" in capsys.readouterr().err and not out.exists()
