"""Evaluation on real-capture terms: a held-out camera without a mask of its own is scored inside the
training cameras' visual hull as it projects there, at the fitted frame and every tracked frame (and
says so), or on the full image only — with the reason — where that hull covers most of the image;
failure signals — floaters, a camera off the others' hull — are warnings in the command's output, not
only JSON fields; the drift verdict says how many Gaussians left the subject and since which frame."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from fitting_scene import moved, ring_camera, subject, write_fitted_run, write_session

from mmcsplat.analysis import rendered_views
from mmcsplat.analysis.drift import detect_drift
from mmcsplat.analysis.rendered_views import HULL_COVERAGE_LIMIT, HULL_MASK, SESSION_MASK, heldout_mask
from mmcsplat.cli import main
from mmcsplat.pipeline.evaluate import failure_signals
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.tracks import TrackReader, TrackWriter
from mmcsplat.training.fitted_run import FittedRun

FRAMES = 3


def write_true_tracks(run: Path, frames: int, displace: Callable[[int, np.ndarray], np.ndarray] | None = None) -> Path:
    """``run``/tracks.zarr: the fitted true subject following its true motion (:func:`fitting_scene.moved`),
    its centres at frame t passed through ``displace(t, means)`` when given."""
    params = FittedRun.load(run).params
    static = {name: params[name] for name in ("log_scales", "opacity_logits", "color_logits", "seg_logits")}
    with TrackWriter(run, num_frames=frames, static=static, method="truth", attrs={"first_frame": 0}) as writer:
        for t in range(frames):
            state = moved(subject(), t)
            means = state.means.numpy()
            writer.write_frame(t, means=displace(t, means) if displace else means, quats=state.quats.numpy())
    return run


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


def _disc(camera, radius: float) -> np.ndarray:
    """[H, W] bool: a disc of ``radius`` px about the world origin's projection in ``camera``."""
    u, v = camera.project(np.zeros((1, 3)))[0]
    rows, cols = np.mgrid[: camera.height, : camera.width]
    return (cols - u) ** 2 + (rows - v) ** 2 <= radius**2


def test_a_hull_covering_most_of_the_image_is_no_subject_mask():
    cameras = [ring_camera(f"cam_{i}", 2 * np.pi * i / 5) for i in range(5)]
    center, radius = np.zeros(3), 1.5
    heldout, trained = cameras[0], cameras[1:]
    own = _disc(heldout, 3)
    session = heldout_mask(own, heldout, 4, [], center, radius)
    assert session.mask is own and (session.source, session.coverage, session.reason) == (SESSION_MASK, None, None)
    # The subject's silhouettes: their hull projects onto part of the held-out image, and is its scoring mask.
    subject = heldout_mask(None, heldout, 4, [(camera, _disc(camera, 6)) for camera in trained], center, radius)
    assert subject.source == HULL_MASK and subject.mask is not None and 0.05 < subject.coverage == subject.mask.mean() < HULL_COVERAGE_LIMIT
    # Masks covering whole images: the hull covers the held-out image, which is then scored unmasked, saying why.
    whole = heldout_mask(None, heldout, 4, [(camera, np.ones((camera.height, camera.width), bool)) for camera in trained], center, radius)
    assert whole.mask is None and whole.coverage == 1.0
    assert whole.reason.startswith("the training cameras' hull covers 100% of its image at frame 4 (more than 80%)")
    lone = heldout_mask(None, heldout, 4, [(trained[0], _disc(trained[0], 6))], center, radius)
    assert lone.mask is None and "1 training camera(s) with a mask at frame 4 (a hull needs two)" in lone.reason


@pytest.fixture(scope="module")
def tracked_run(tmp_path_factory):
    """A perfect fit of a 3-frame moving subject with perfect tracks; held-out cam_0 has no masks."""
    root = tmp_path_factory.mktemp("tracked")
    session = write_session(root / "s.zarr", frames=FRAMES, unmasked=("cam_0",))
    return write_true_tracks(write_fitted_run(root / "run", session), FRAMES)


def test_tracked_frames_are_scored_in_their_own_frames_hull(tracked_run, capsys):
    assert main(["evaluate", str(tracked_run), "--no-progress"]) == 0
    table = capsys.readouterr().out.splitlines()
    metrics = json.loads((tracked_run / "metrics.json").read_text())
    assert metrics["per_camera"]["cam_0"]["mask"] == HULL_MASK and metrics["warnings"] == []
    # Every tracked frame scored in the hull of that frame's training masks, close to the true image.
    per_frame = metrics["per_frame_val_masked_psnr"]
    assert len(per_frame) == FRAMES and all(value is not None and value > 25 for value in per_frame)
    assert per_frame[0] == pytest.approx(metrics["val_masked_psnr"], abs=0.01) and metrics["tracked_val_unmasked"] == {}
    assert metrics["tracked_val_masked_psnr"] == pytest.approx(np.mean(per_frame))
    # The console puts the tracked frames' mean beside the fitted frame's.
    assert table[0].split() == ["fitted", "frame", "tracked", "frames", "(mean)"]
    row = next(line for line in table if line.startswith("val_masked_psnr")).split()
    assert [float(value) for value in row[1:]] == pytest.approx([metrics["val_masked_psnr"], metrics["tracked_val_masked_psnr"]], abs=1e-3)
    assert metrics["drift"] is False and metrics["drift_since_frame"] is None
    assert metrics["drift_summary"].startswith("no drift: 0 of 150 foreground Gaussians left the subject")


def test_a_heldout_view_scored_unmasked_says_why(tracked_run, capsys, monkeypatch):
    monkeypatch.setattr(rendered_views, "HULL_COVERAGE_LIMIT", 0.0)  # every hull counts as covering the image
    assert main(["evaluate", str(tracked_run), "--no-progress"]) == 0
    err = capsys.readouterr().err
    metrics = json.loads((tracked_run / "metrics.json").read_text())
    cam_0 = metrics["per_camera"]["cam_0"]
    assert "masked_psnr" not in cam_0 and "mask" not in cam_0 and cam_0["mask_coverage"] > 0
    assert cam_0["unmasked"].startswith("the training cameras' hull covers") and metrics["val_masked_psnr"] is None
    assert metrics["val_psnr"] == cam_0["psnr"] and metrics["per_frame_val_masked_psnr"] == [None] * FRAMES
    assert metrics["tracked_val_unmasked"]["cam_0"]["frames"] == FRAMES and metrics["tracked_val_psnr"] is not None
    assert f"warning: {tracked_run}: camera 'cam_0': no masked score at the fitted frame: the training cameras' hull covers" in err
    assert f"camera 'cam_0': no masked score at {FRAMES} tracked frame(s)" in err


def test_the_drift_verdict_says_how_many_gaussians_left_and_since_when(tracked_run, tmp_path):
    reader = SessionReader(FittedRun.load(tracked_run).info.session)
    run = write_fitted_run(tmp_path / "run", reader.url)
    away = np.zeros(len(subject().means), dtype=bool)
    away[:20] = True  # 20 of the 150 Gaussians fly 40 cm up from frame 2 on
    write_true_tracks(run, FRAMES, lambda t, means: means + (0.4 if t >= 2 else 0.0) * away[:, None] * np.array([0, 0, 1.0]))
    report = detect_drift(TrackReader(run), reader, list(reader.train_cameras))
    assert report.drift and report.since == 2 and len(report.drifted) == 20 and report.counts == [0, 0, 20]
    assert report.explain() == ("drift: 20 of 150 foreground Gaussians left the subject, more than the first frame's share + 2% since "
                                "frame 2; at most 20 at once (frame 2, 13.3%; 0 at the first frame)")
