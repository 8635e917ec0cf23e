"""Tracking accuracy against ground-truth points, the ground truth's location and frame mapping, and the
drift detector's geometry — on tracks and masks made here, without rendering."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
import zarr
from fitting_scene import ring_camera

from mmcsplat.analysis.drift import off_subject
from mmcsplat.analysis.trajectory_error import NothingFollowedError, evaluate_tracks, follower_weights, tracking_accuracy
from mmcsplat.storage.ground_truth import GROUND_TRUTH, GroundTruthReader, ground_truth_beside
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.tracks import TrackReader, TrackWriter

T, P = 4, 30


def ground_truth() -> np.ndarray:
    """[T, P, 3]: points on a 20 cm sphere moving 1 cm per frame along x and spreading 2 % per frame."""
    g = np.random.default_rng(0)
    points = g.normal(size=(P, 3))
    points = 0.2 * points / np.linalg.norm(points, axis=1, keepdims=True)
    return np.stack([points * (1 + 0.02 * t) + [0.01 * t, 0, 0] for t in range(T)])


def write_tracks(run, means: np.ndarray) -> TrackReader:
    """Tracks whose Gaussian centres are ``means`` [T, N, 3]."""
    n = means.shape[1]
    static = {"log_scales": torch.zeros(n, 3), "opacity_logits": torch.zeros(n), "color_logits": torch.zeros(n, 3),
              "seg_logits": torch.ones(n, 1)}
    with TrackWriter(run, num_frames=len(means), static=static, method="test") as writer:
        for t, frame in enumerate(means):
            writer.write_frame(t, means=frame, quats=np.tile([1.0, 0, 0, 0], (n, 1)))
    return TrackReader(run)


def test_perfect_tracks_have_no_error(tmp_path):
    truth = ground_truth()
    camera = ring_camera("cam", 0.0)
    accuracy = tracking_accuracy(write_tracks(tmp_path, truth), truth, camera)
    assert accuracy.median_mm == pytest.approx(0, abs=1e-3) and accuracy.p90_mm == pytest.approx(0, abs=1e-3)
    assert accuracy.median_2d_px == pytest.approx(0, abs=1e-3)
    assert accuracy.followed_points == accuracy.total_points == P
    still = np.median(np.linalg.norm(truth[1:] - truth[0], axis=2)) * 1000
    assert accuracy.still_median_mm == pytest.approx(still, rel=1e-5)


def test_errors_are_the_mean_displacement_against_the_points(tmp_path):
    truth = ground_truth()
    # Two Gaussians 3 mm either side of each point follow it: one exactly, one lagging 8 mm behind from
    # frame 1 on, so their mean displacement is off by 4 mm. Points on the far side are not followed.
    offset = np.array([0.003, 0, 0])
    lag = np.array([[0, 0, 0]] + [[-0.008, 0, 0]] * (T - 1))[:, None]
    means = np.concatenate([truth + offset, truth - offset + lag], axis=1)
    accuracy = tracking_accuracy(write_tracks(tmp_path, means), truth, ring_camera("cam", 0.0))
    assert accuracy.median_mm == pytest.approx(4.0, rel=1e-4) and accuracy.p90_mm == pytest.approx(4.0, rel=1e-4)
    assert accuracy.per_frame_median_mm == pytest.approx([0, 4, 4, 4], rel=1e-4)
    # 4 mm along x at 1.2 m with a 40 px focal length: about 0.13 px, less where x is not across the view.
    assert 0 < accuracy.median_2d_px < 40 * 0.004 / 1.0


def test_points_without_a_gaussian_nearby_are_left_out(tmp_path):
    points = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    means = np.array([[0.004, 0, 0], [-0.004, 0, 0], [2.02, 0, 0]])
    weights, followed = follower_weights(means, points, radius=0.01)
    assert followed.tolist() == [0]
    np.testing.assert_allclose(weights.toarray(), [[0.5, 0.5, 0.0]])
    with pytest.raises(NothingFollowedError, match=r"no ground-truth surface point has a Gaussian within 10 mm .*nearest 7680 mm; 3 Gaussians, 3 points"):
        tracking_accuracy(write_tracks(tmp_path, np.stack([means + 5, means + 5])), np.stack([points, points]))


def test_evaluate_reports_why_nothing_was_followed_instead_of_failing(tmp_path):
    truth = ground_truth()
    path = tmp_path / "truth.zarr"
    zarr.open_group(str(path), mode="w", zarr_format=3).create_array("surface_points", data=truth)
    (tmp_path / "run").mkdir()
    write_tracks(tmp_path / "run", truth + [0.5, 0, 0])  # the whole fit 50 cm off the subject
    metrics = evaluate_tracks(tmp_path / "run", SimpleNamespace(capture_frames=lambda frames: np.asarray(frames), provenance={}, url="s.zarr"), [], path)
    assert metrics["tracking_median_mm"] is metrics["tracking_p90_mm"] is metrics["tracking_2d_median_px"] is None
    assert (metrics["tracking_followed_points"], metrics["tracking_ground_truth_points"]) == (0, P)
    assert metrics["tracking_error"].startswith("no ground-truth surface point has a Gaussian within 10 mm at the first tracked frame")
    assert "tracking_per_frame_median_mm" not in metrics


def test_ground_truth_location_and_frame_mapping(tmp_path):
    source = tmp_path / "capture"
    (source / GROUND_TRUTH).mkdir(parents=True)
    assert ground_truth_beside(SimpleNamespace(source=str(source))) == source / GROUND_TRUTH
    assert ground_truth_beside(SimpleNamespace(source=str(tmp_path))) is None
    assert ground_truth_beside(SimpleNamespace(source="")) is None
    # ingest --frames 2:10:2 made session frame k capture frame 2 + 2k.
    def ingested(provenance: dict) -> SimpleNamespace:
        session = SimpleNamespace(provenance=provenance)
        session.capture_start_step = SessionReader.capture_start_step.fget(session)
        return session

    capture_frames = SessionReader.capture_frames
    assert capture_frames(ingested({"frames": [2, 10, 2]}), range(1, 4)).tolist() == [4, 6, 8]
    assert capture_frames(ingested({}), range(3)).tolist() == [0, 1, 2]


def test_read_surface_points(tmp_path):
    truth = ground_truth().astype(np.float32)
    path = tmp_path / "truth.zarr"
    zarr.open_group(str(path), mode="w", zarr_format=3).create_array("surface_points", data=truth)
    np.testing.assert_allclose(GroundTruthReader(path).points("surface_points", np.array([1, 3])), truth[[1, 3]])
    with pytest.raises(ValueError, match="has 4 frames, the tracks need frame 7"):
        GroundTruthReader(path).points("surface_points", np.array([0, 7]), "the tracks need frame")
    zarr.open_group(str(tmp_path / "other.zarr"), mode="w", zarr_format=3)
    with pytest.raises(ValueError, match="other.zarr: not a ground truth"):
        GroundTruthReader(tmp_path / "other.zarr").points("surface_points", np.array([0]))


def test_off_subject_is_judged_by_the_views_that_see_a_point():
    cameras = [ring_camera(f"cam_{i}", 2 * np.pi * i / 3) for i in range(3)]
    # Each view's mask: a disc of 5 px around the projected origin.
    masks = []
    for camera in cameras:
        u, v = camera.project(np.zeros((1, 3)))[0]
        rows, cols = np.mgrid[: camera.height, : camera.width]
        masks.append((cols - u) ** 2 + (rows - v) ** 2 <= 25)
    views = list(zip(cameras, masks, strict=True))
    points = np.array([[0.0, 0, 0], [0.0, 0, 0.5], [0, 0, 50.0]])  # on the subject; above it; behind every camera
    assert off_subject(points, views).tolist() == [False, True, False]
    # Outside only in the first view: off the subject at a one-third threshold, not at one half.
    outside_one = np.array([[0.0, 0, 0]])
    masks_one = [masks[0] & False, masks[1], masks[2]]
    assert off_subject(outside_one, list(zip(cameras, masks_one, strict=True)), 0.5).tolist() == [False]
    assert off_subject(outside_one, list(zip(cameras, masks_one, strict=True)), 1 / 3).tolist() == [True]
