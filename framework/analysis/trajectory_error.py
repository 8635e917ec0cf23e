"""How well a dynamic run's Gaussians follow the body: 3D and 2D trajectory errors against ground-truth
surface points.

Ground truth is a zarr group holding ``surface_points`` [T, P, 3] float (world metres, the session's
world frame, indexed by the capture's frame numbers) — what ``mmcsplat synth`` writes as
``ground_truth.zarr`` beside its videos. The core reads that array itself (it knows no dataset plugin):
a path given explicitly wins; otherwise :func:`~mmcsplat.storage.ground_truth.ground_truth_beside` looks beside the session's source
folder. Session frames map to capture frames through the ingest provenance (``frames`` start/step).

For every ground-truth point, the Gaussians within :data:`FOLLOW_RADIUS` of it at the first tracked
frame follow it: the point's estimated position at frame k is its first position plus their mean
displacement. Errors are taken over every followed point and every later frame. When no point has a
Gaussian that near (a fit in the wrong place), the errors are not measured and ``tracking_error`` says why.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import attrs
import numpy as np
import scipy.sparse
from scipy.spatial import cKDTree

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.ground_truth import GroundTruthReader, ground_truth_beside, ground_truth_gone
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.tracks import TrackReader

FOLLOW_RADIUS = 0.01  # metres


class NothingFollowedError(InputError):
    """No ground-truth point has a Gaussian within the follow radius at the first tracked frame, so no
    tracking error can be measured."""


@attrs.frozen
class TrackingAccuracy:
    """Trajectory errors over frames 1… of the tracks: 3D in millimetres, 2D in the held-out camera's
    pixels (``None`` without one); ``per_frame_median_mm`` [T] (0 at frame 0); ``still_median_mm``, the
    median error Gaussians that never moved would have (how far the followed points move: the number
    to beat); how many ground-truth points had a Gaussian within the follow radius at the first frame."""

    median_mm: float
    p90_mm: float
    still_median_mm: float
    median_2d_px: float | None
    per_frame_median_mm: list[float]
    followed_points: int
    total_points: int


def follower_weights(first_means: np.ndarray, points: np.ndarray, radius: float = FOLLOW_RADIUS) -> tuple[scipy.sparse.csr_matrix, np.ndarray]:
    """(W [P', N] whose rows average the Gaussians within ``radius`` of a point, the indices [P'] of the
    points that have any)."""
    groups = cKDTree(first_means).query_ball_point(points, r=radius)
    followed = np.array([i for i, group in enumerate(groups) if group], dtype=int)
    rows, cols, values = [], [], []
    for row, i in enumerate(followed):
        rows += [row] * len(groups[i])
        cols += groups[i]
        values += [1.0 / len(groups[i])] * len(groups[i])
    weights = scipy.sparse.csr_matrix((values, (rows, cols)), shape=(len(followed), len(first_means)))
    return weights, followed


def tracking_accuracy(tracks: TrackReader, truth: np.ndarray, camera: Camera | None = None, radius: float = FOLLOW_RADIUS) -> TrackingAccuracy:
    """Compare ``tracks`` with ``truth`` [T, P, 3] (ground-truth points at the tracks' frames); the 2D
    error is measured in ``camera`` (points whose true position projects inside its image)."""
    if truth.shape[0] != tracks.num_frames:
        raise InputError(f"ground truth has {truth.shape[0]} frames, the tracks {tracks.num_frames}")
    first = tracks.means(0).astype(np.float64)
    weights, followed = follower_weights(first, truth[0], radius)
    if not len(followed):
        nearest = np.min(cKDTree(first).query(truth[0])[0], initial=np.inf) * 1000.0
        raise NothingFollowedError(
            f"no ground-truth surface point has a Gaussian within {radius * 1000:.0f} mm at the first tracked frame "
            f"(nearest {nearest:.0f} mm; {len(first)} Gaussians, {truth.shape[1]} points): is the fit in the right place?"
        )
    start = truth[0, followed]
    errors, still, pixel_errors, per_frame = [], [], [], [0.0]
    for k in range(1, tracks.num_frames):
        estimate = start + weights @ (tracks.means(k).astype(np.float64) - first)
        actual = truth[k, followed]
        error = np.linalg.norm(estimate - actual, axis=1) * 1000.0
        errors.append(error)
        still.append(np.linalg.norm(actual - start, axis=1) * 1000.0)
        per_frame.append(float(np.median(error)))
        if camera is not None:
            pixel_errors.append(_pixel_errors(camera, estimate, actual))
    errors_all = np.concatenate(errors) if errors else np.zeros(1)
    pixels = np.concatenate(pixel_errors) if pixel_errors else np.zeros(0)
    return TrackingAccuracy(
        median_mm=float(np.median(errors_all)),
        p90_mm=float(np.percentile(errors_all, 90)),
        still_median_mm=float(np.median(np.concatenate(still))) if still else 0.0,
        median_2d_px=float(np.median(pixels)) if len(pixels) else None,
        per_frame_median_mm=per_frame,
        followed_points=len(followed),
        total_points=int(truth.shape[1]),
    )


def _pixel_errors(camera: Camera, estimate: np.ndarray, actual: np.ndarray) -> np.ndarray:
    depth = (actual @ camera.R.T + camera.t)[:, 2]
    true_pixels = camera.project(actual)
    inside = (depth > 0) & np.all((true_pixels >= -0.5) & (true_pixels < [camera.width - 0.5, camera.height - 0.5]), axis=1)
    return np.linalg.norm(camera.project(estimate[inside]) - true_pixels[inside], axis=1)


def evaluate_tracks(run: Path, session: SessionReader, heldout: list[str], ground_truth: str | Path | None = None) -> dict[str, Any]:
    """The tracking metrics of ``run``: ``tracking_median_mm``, ``tracking_p90_mm``,
    ``tracking_2d_median_px`` (in the first of the ``heldout`` cameras; ``None`` when no ground truth is
    found, and ``None`` with the reason in ``tracking_error`` when no ground-truth point is followed or the
    capture's ground truth recorded at ingest is gone),
    ``tracking_followed_points``, ``tracking_per_frame_median_mm``, ``tracking_num_gaussians`` (the tracked
    model's size: a method that densifies while tracking ends larger than the first-frame fit, whose size
    is ``num_gaussians``). The held-out views' scores at every frame are
    :func:`~mmcsplat.analysis.rendered_views.tracked_heldout_scores`'s."""
    tracks = TrackReader(run)
    frames = range(int(tracks.attrs.get("first_frame", 0)), int(tracks.attrs.get("first_frame", 0)) + tracks.num_frames)
    metrics: dict[str, Any] = {"tracking_method": tracks.method, "tracking_num_gaussians": tracks.num_gaussians}
    path = Path(ground_truth) if ground_truth is not None else ground_truth_beside(session)
    if path is None:
        metrics.update(tracking_median_mm=None, tracking_p90_mm=None, tracking_2d_median_px=None)
        if (gone := ground_truth_gone(session)) is not None:  # else a capture without ground truth: nothing to say
            metrics["tracking_error"] = (f"the capture's ground truth {gone} (recorded at ingest) is gone — the capture was moved or deleted: "
                                         "pass --ground-truth PATH")
        return metrics
    reader = GroundTruthReader(path)
    reader.require_truth_of(session)
    truth = reader.points("surface_points", session.capture_frames(frames), "the tracks need frame")
    metrics.update(tracking_ground_truth=str(path), tracking_ground_truth_points=int(truth.shape[1]))
    try:
        accuracy = tracking_accuracy(tracks, truth, session.camera(heldout[0]) if heldout else None)
    except NothingFollowedError as error:  # a bad run: its other metrics still tell how bad
        metrics.update(tracking_median_mm=None, tracking_p90_mm=None, tracking_2d_median_px=None, tracking_followed_points=0,
                       tracking_error=str(error))
        return metrics
    metrics.update(
        tracking_median_mm=accuracy.median_mm,
        tracking_p90_mm=accuracy.p90_mm,
        tracking_still_median_mm=accuracy.still_median_mm,
        tracking_2d_median_px=accuracy.median_2d_px,
        tracking_per_frame_median_mm=accuracy.per_frame_median_mm,
        tracking_followed_points=accuracy.followed_points,
    )
    return metrics
