"""Held-out-camera evaluation of a fit run: renders every camera of the fitted frame and scores it with
the metric plugins, the way the reference study did (PSNR inside the subject mask on the held-out view)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from mmcsplat.analysis.drift import detect_drift
from mmcsplat.analysis.rendered_views import render_over
from mmcsplat.analysis.trajectory_error import evaluate_tracks
from mmcsplat.analysis.visual_hull import FLOATER_MARGIN_PX, dilated, eroded, floater_share, mask_agreement, projected_hull_mask
from mmcsplat.configuration.registry import Registry, default_registry
from mmcsplat.pipeline.fit import fitted_background, load_fitted
from mmcsplat.pipeline.landmarks import recorded_lost
from mmcsplat.plugin_api.errors import MissingFileError
from mmcsplat.plugin_api.render_contract import gaussians_from_params
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.atomic import write_json_atomic
from mmcsplat.storage.run_info import RUN_INFO
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.tracks import TRACKS_DIR, TrackReader
from mmcsplat.training.backdrop import camera_backdrop
from mmcsplat.training.supersampling import run_renderer

METRICS_FILE = "metrics.json"
#: Above this share of the opacity outside the masks' visual hull, a fit is mostly floaters (the reference
#: study's failure mode; the demo's fits hold 2–5 %).
FLOATER_WARNING = 0.3
#: Below this share of its mask on the other cameras' hull, a camera's calibration or mask is suspect
#: (docs/outputs.md: the synthetic capture's cameras score 0.95–1).
AGREEMENT_WARNING = 0.6


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def _mask_views(session: SessionReader, frame: int) -> list[tuple[Camera, np.ndarray]]:
    """(camera, mask) of every camera with a mask at ``frame``."""
    views = []
    for name in session.camera_names:
        mask = session.frame(frame, name).mask if session.present(name)[frame] else None
        if mask is not None:
            views.append((session.camera(name), mask))
    return views


def _floater_share(views: list[tuple[Camera, np.ndarray]], params: dict[str, torch.Tensor]) -> float | None:
    """:func:`~mmcsplat.analysis.visual_hull.floater_share` of the fitted Gaussians against the hull of the
    ``views``' masks (dilated by :data:`~mmcsplat.analysis.visual_hull.FLOATER_MARGIN_PX`); ``None`` without masks."""
    if not views:
        return None
    opacities = torch.sigmoid(params["opacity_logits"].detach()).double().numpy()
    return floater_share(params["means"].detach().double().numpy(), opacities, [(camera, dilated(mask, FLOATER_MARGIN_PX)) for camera, mask in views])


def _mask_agreement(views: list[tuple[Camera, np.ndarray]], center: np.ndarray, radius: float) -> dict[str, float]:
    """Per camera with a non-empty mask, :func:`~mmcsplat.analysis.visual_hull.mask_agreement` with the hull of
    the others' masks (dilated by :data:`~mmcsplat.analysis.visual_hull.FLOATER_MARGIN_PX`), forgiving one other
    view that disagrees when at least three others see a point — so that one camera's wrong extrinsics
    or wrong mask lower its own score, not everyone's. Needs two other cameras at least."""
    grown = [(camera, dilated(mask, FLOATER_MARGIN_PX)) for camera, mask in views]
    scores = {}
    for index, (camera, mask) in enumerate(views):
        others = grown[:index] + grown[index + 1:]
        if len(others) >= 2 and (score := mask_agreement(camera, mask, others, center, radius, tolerance=1 if len(others) >= 3 else 0)) is not None:
            scores[camera.name] = score
    return scores


def failure_signals(floaters: float | None, agreement: dict[str, float]) -> list[str]:
    """One warning per failure signal above its threshold: floaters, cameras off the others' hull."""
    warnings = []
    if floaters is not None and floaters > FLOATER_WARNING:
        warnings.append(f"{floaters:.0%} of the opacity lies outside the subject's visual hull (floaters): the start or pruning region may "
                        "not fit the subject, or too few cameras constrain it — see docs/fit.md")
    for name, score in sorted(agreement.items()):
        if score < AGREEMENT_WARNING:
            warnings.append(f"camera {name!r}: only {score:.0%} of its mask lies on the other cameras' visual hull — its calibration "
                            "(units, a duplicated pose) or its masks are suspect")
    return warnings


def fit_signals(run: Path) -> list[str]:
    """:func:`failure_signals` of a fitted run, from its Gaussians and the session's masks (no rendering)."""
    info, params, _, _ = load_fitted(run)
    views = _mask_views(SessionReader(info.session), info.frame)
    return failure_signals(_floater_share(views, params), _mask_agreement(views, np.asarray(info.scene_center), info.scene_scale))


def evaluate_run(run: Path, registry: Registry | None = None, backend: str | None = None, ground_truth: Path | None = None) -> dict[str, Any]:
    """Score one run directory and write its metrics.json; returns the metrics. A run with tracks
    (``mmcsplat track``) also gets the tracking metrics of :mod:`mmcsplat.analysis.trajectory_error` (against
    ``ground_truth``, or the one found beside the session's source) and the drift report of
    :mod:`mmcsplat.analysis.drift`; one with landmarks (``mmcsplat landmarks``) gets their ``lost_landmarks``
    record. ``floater_share`` is the share of opacity mass outside the visual hull of the
    session's masks at the fitted frame, ``mask_agreement`` per camera the share of its mask on the hull
    of the other cameras' masks (:mod:`mmcsplat.analysis.visual_hull`; low for a camera with wrong extrinsics)."""
    registry = registry or default_registry()
    info, params, camera_scale, camera_offset = load_fitted(run)
    session = SessionReader(info.session)
    renderer = run_renderer(info, registry, backend)
    psnr = registry.create("metric", "psnr")
    ssim = registry.create("metric", "ssim")
    gaussians = gaussians_from_params(params)
    frame = info.frame
    views = _mask_views(session, frame)
    background = fitted_background(info)
    scores: dict[str, dict[str, list[float]]] = {"val": {}, "train": {}}
    per_camera = {}
    # A moving camera's poses are cameras present at one frame each: only those imaging the fitted frame are scored.
    names = [name for name in (*info.train_cameras, *info.heldout_cameras) if session.present(name)[frame]]
    for name in names:
        split = "train" if name in info.train_cameras else "val"
        data = session.frame(frame, name)
        rgb = render_over(renderer, gaussians, session.camera(name), camera_backdrop(background, session, name))
        if split == "train":  # training views are scored through their learnt colour correction
            index = info.train_cameras.index(name)
            rgb = rgb * camera_scale[index] + camera_offset[index]
        prediction = rgb.clamp(0, 1).double().numpy()
        target = data.rgb.astype(np.float64) / 255.0
        camera_scores = {"psnr": psnr(prediction, target), "ssim": ssim(prediction, target)}
        mask, mask_source = data.mask, "session"
        if mask is None and split == "val":  # no mask of its own: where the training cameras' hull projects
            others = [(camera, view_mask) for camera, view_mask in views if camera.name in info.train_cameras]
            if len(others) >= 2:
                mask = projected_hull_mask(session.camera(name), others, np.asarray(info.scene_center), info.scene_scale)
                mask_source = "hull of the training cameras' masks"
        if mask is not None and mask.any():
            camera_scores["masked_psnr"] = psnr(prediction, target, mask)
            camera_scores["mask"] = mask_source
            interior = eroded(mask, 1)
            if interior.any():
                camera_scores["interior_masked_psnr"] = psnr(prediction, target, interior)
        per_camera[name] = {"split": split, **camera_scores}
        for key, value in camera_scores.items():
            if key != "mask":
                scores[split].setdefault(key, []).append(value)
    floaters = _floater_share(views, params)
    agreement = _mask_agreement(views, np.asarray(info.scene_center), info.scene_scale)
    metrics = {
        "val_masked_psnr": _mean(scores["val"].get("masked_psnr", [])),
        "val_psnr": _mean(scores["val"].get("psnr", [])),
        "val_ssim": _mean(scores["val"].get("ssim", [])),
        "train_masked_psnr": _mean(scores["train"].get("masked_psnr", [])),
        "val_interior_masked_psnr": _mean(scores["val"].get("interior_masked_psnr", [])),
        "train_interior_masked_psnr": _mean(scores["train"].get("interior_masked_psnr", [])),
        "train_psnr": _mean(scores["train"].get("psnr", [])),
        "num_gaussians": int(params["means"].shape[0]),
        "floater_share": floaters,
        "mask_agreement": agreement,
        "warnings": failure_signals(floaters, agreement),
        "iterations": info.iterations,
        "wall_s": info.wall_s,
        "status": info.status,
        "heldout_cameras": list(info.heldout_cameras),
        "per_camera": per_camera,
    }
    if (Path(run) / TRACKS_DIR).exists():
        metrics.update(evaluate_tracks(Path(run), session, info.heldout_cameras, ground_truth, renderer, psnr, background))
        report = detect_drift(TrackReader(run), session, info.train_cameras)
        metrics.update(drift=report.drift, drift_per_frame=report.counts, drift_foreground=report.foreground)
    if (lost := recorded_lost(run)) is not None:
        metrics["lost_landmarks"] = lost
    write_json_atomic(Path(run) / METRICS_FILE, metrics)
    return metrics


def fold_runs(run: Path) -> list[Path]:
    """The fold sub-directories of a leave-one-camera-out run, or ``[run]`` for a single fit."""
    run = Path(run)
    if (run / RUN_INFO).exists():
        return [run]
    folds = sorted(path for path in run.iterdir() if (path / RUN_INFO).exists()) if run.is_dir() else []
    if not folds:
        raise MissingFileError(f"{run} holds no fit run ({RUN_INFO}) nor fold runs")
    return folds


def evaluate(run: Path, registry: Registry | None = None, backend: str | None = None, ground_truth: Path | None = None) -> dict[str, Any]:
    """Evaluate a run or every fold of a leave-one-camera-out run; folds are averaged into RUN/metrics.json."""
    runs = fold_runs(run)
    if runs == [Path(run)]:
        return evaluate_run(Path(run), registry, backend, ground_truth)
    folds = {path.name: evaluate_run(path, registry, backend, ground_truth) for path in runs}
    summary: dict[str, Any] = {}
    for key in ("val_masked_psnr", "val_psnr", "val_ssim", "train_masked_psnr", "val_interior_masked_psnr", "train_interior_masked_psnr", "train_psnr", "num_gaussians", "floater_share", "iterations", "wall_s"):
        values = [m[key] for m in folds.values() if m[key] is not None]
        summary[key] = _mean(values)
    summary["val_masked_psnr_std"] = float(np.std([m["val_masked_psnr"] for m in folds.values() if m["val_masked_psnr"] is not None] or [np.nan]))
    summary["folds"] = folds
    write_json_atomic(Path(run) / METRICS_FILE, summary)
    return summary
