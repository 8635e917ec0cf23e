"""Fitting over clean plates (``fit.background = "plate"``): the setting, the loss targets, a fit that
learns, evaluation and tracking scored over each camera's plate, and a session without plates refused."""

from __future__ import annotations

import numpy as np
import pytest
from fitting_scene import plate, subject, write_config, write_fitted_run, write_session

from mmcsplat.configuration.config import load_config
from mmcsplat.configuration.registry import default_registry
from mmcsplat.pipeline.evaluate import evaluate
from mmcsplat.pipeline.fit import FirstFrameFit
from mmcsplat.pipeline.track import track_run
from mmcsplat.storage.session import SessionReader
from mmcsplat.training.backdrop import PLATE, camera_backdrop, parse_background
from mmcsplat.training.views import load_view

TRUTH = subject(count=60, scale=0.02)


@pytest.fixture(scope="module")
def plated(tmp_path_factory) -> SessionReader:
    """The fitting scene in front of each camera's plate (checks over a colour ramp), plates stored."""
    return SessionReader(write_session(tmp_path_factory.mktemp("plated") / "scene.zarr", frames=2, zoom=2, truth=TRUTH, plates=True))


def test_the_setting_is_a_colour_or_plate():
    assert parse_background("plate") == PLATE and parse_background([0, 0.5, 1]) == (0.0, 0.5, 1.0)
    for bad in ("plates", [0.1, 0.2], [0.0, float("nan"), 0.0]):
        with pytest.raises(ValueError, match="fit.background must be 'plate' or an RGB colour"):
            parse_background(bad)


def test_masked_targets_show_the_plate_outside_the_subject(plated):
    camera = plated.camera("cam_1")
    view = load_view(plated, 0, camera, 0, [default_registry().create("initializer", "masked")], camera_backdrop(PLATE, plated, "cam_1"))
    data = plated.frame(0, "cam_1")
    expected = np.where(data.mask[..., None], data.rgb, plate(camera)) / 255.0
    np.testing.assert_allclose(view.image.numpy(), expected, atol=1e-6)


def test_a_session_without_plates_is_refused_naming_the_camera(tmp_path):
    session = SessionReader(write_session(tmp_path / "bare.zarr"))
    config = load_config(write_config(tmp_path / "fit.toml", background='"plate"'))
    with pytest.raises(ValueError, match=r"no clean plate of camera 'cam_1'.*--plates DIR"):
        FirstFrameFit(session, config, tmp_path / "run", progress=False)


def test_evaluation_and_tracking_score_over_the_plates(plated, tmp_path):
    """The true subject over each camera's plate is the capture itself: the whole held-out image matches,
    the plate included; scored over black, only the subject would."""
    scores = {}
    for background in ("plate", None):
        run = write_fitted_run(tmp_path / str(background), plated.url, TRUTH, background=f"{background}" if background else None)
        scores[background] = evaluate(run)
    assert scores["plate"]["val_psnr"] > 40 and scores[None]["val_psnr"] < 12
    assert scores["plate"]["val_masked_psnr"] > scores[None]["val_masked_psnr"] + 10  # the outline's pixels mix the plate in
    run = tmp_path / "plate"
    track_run(run, dynamics="iterative", overrides=["dynamics.iterations=20"], progress=False)
    assert min(evaluate(run)["per_frame_val_masked_psnr"]) > 28  # ~17 dB scored over black


def test_a_fit_over_plates_learns(plated, tmp_path):
    config = load_config(write_config(tmp_path / "fit.toml", iterations=60, background='"plate"'))
    FirstFrameFit(plated, config, tmp_path / "run", progress=False).run()
    metrics = evaluate(tmp_path / "run")
    # Over black the whole held-out image scores ~10 dB (the plate is missing); over the plate, far more.
    assert metrics["train_masked_psnr"] > 14 and metrics["val_psnr"] > 20
