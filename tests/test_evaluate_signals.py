"""Evaluation on real-capture terms: a held-out camera without a mask of its own is scored inside the
training cameras' visual hull as it projects there (and says so); failure signals — floaters, a camera
off the others' hull — are warnings in the command's output, not only JSON fields."""

from __future__ import annotations

import json

from fitting_scene import write_fitted_run, write_session

from mmcsplat.cli import main
from mmcsplat.pipeline.evaluate import failure_signals
from mmcsplat.storage.session import SessionReader


def test_a_heldout_camera_without_a_mask_is_scored_in_the_projected_hull(tmp_path):
    session = write_session(tmp_path / "s.zarr", masks=False, plates=True)
    trained = ",".join(name for name in SessionReader(session).camera_names if name != "cam_0")
    assert main(["segment", str(session), "--segmenter", "background", "--set", "method=plate", "--cameras", trained, "--no-progress"]) == 0
    reader = SessionReader(session)
    assert not reader.has("mask", "cam_0") and reader.has("mask", "cam_1")
    run = write_fitted_run(tmp_path / "run", session, background="plate")
    assert main(["evaluate", str(run)]) == 0
    metrics = json.loads((run / "metrics.json").read_text())
    cam_0 = metrics["per_camera"]["cam_0"]
    assert cam_0["mask"] == "hull of the training cameras' masks" and metrics["per_camera"]["cam_1"]["mask"] == "session"
    # The true subject fitted: inside the projected hull the held-out view is close to the image.
    assert cam_0["masked_psnr"] > 25 and metrics["val_masked_psnr"] == cam_0["masked_psnr"]


def test_failure_signals_name_what_is_wrong():
    assert failure_signals(0.05, {"cam_0": 0.98, "cam_1": 0.97}) == []
    warnings = failure_signals(0.87, {"cam_0": 0.98, "cam_1": 0.33})
    assert len(warnings) == 2 and warnings[0].startswith("87% of the opacity lies outside")
    assert "camera 'cam_1': only 33% of its mask" in warnings[1]
    assert failure_signals(None, {}) == []


def test_fit_prints_its_failure_signals(tmp_path, capsys):
    from fitting_scene import write_config

    session = write_session(tmp_path / "s.zarr")
    config = write_config(tmp_path / "fit.toml", iterations=1, checkpoint_every=1)
    assert main(["fit", str(session), "--config", str(config), "--out", str(tmp_path / "run"), "--no-progress"]) == 0
    # One iteration from a random cube: most of the opacity is off the subject, and the command says so.
    assert "of the opacity lies outside the subject's visual hull (floaters)" in capsys.readouterr().err
